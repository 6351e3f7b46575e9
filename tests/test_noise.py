"""3D-noise statistics from leave-one-out differences, noise injection and the Algorithm-1 pair schedule."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from go_core.gaussians import Gaussians
from go_core.repair.noise import NoiseStats, PairSchedule, add_noise, difference_stats


def _random_gaussians(n: int, seed: int) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians(
        torch.randn(n, 3, generator=g),
        torch.randn(n, 4, generator=g),
        torch.randn(n, 3, generator=g),
        torch.randn(n, generator=g),
        torch.randn(n, 9, 3, generator=g),
    )


def test_difference_stats_match_numpy():
    pairs = [(_random_gaussians(50, s), _random_gaussians(50, s + 10)) for s in range(3)]
    stats = difference_stats(pairs)
    assert stats.count == 150
    d = np.concatenate([a.means.numpy().astype(np.float64) - b.means.numpy() for b, a in pairs])
    np.testing.assert_allclose(stats.mean["means"], d.mean(0), rtol=1e-6)
    np.testing.assert_allclose(stats.std["means"], d.std(0, ddof=1), rtol=1e-6)
    q = np.concatenate([(a.normalized_quats() - b.normalized_quats()).numpy() for b, a in pairs])
    np.testing.assert_allclose(stats.mean["quats"], q.mean(0), rtol=1e-5, atol=1e-7)
    assert len(stats.std["opacity_logits"]) == 1 and "sh" not in stats.mean
    assert NoiseStats.from_json(stats.to_json()) == stats
    with pytest.raises(ValueError):
        difference_stats([(_random_gaussians(5, 0), _random_gaussians(6, 0))])


def test_add_noise_follows_stats_and_leaves_sh():
    g = _random_gaussians(20000, 1)
    stats = NoiseStats(
        mean={
            "means": [0.1, -0.2, 0.0],
            "log_scales": [0.05] * 3,
            "quats": [0.0] * 4,
            "opacity_logits": [-0.3],
        },
        std={
            "means": [0.01, 0.02, 0.03],
            "log_scales": [0.1] * 3,
            "quats": [0.0] * 4,
            "opacity_logits": [0.2],
        },
        count=1,
    )
    noisy = add_noise(g, stats, torch.Generator().manual_seed(0))
    d = (noisy.means - g.means).double()
    np.testing.assert_allclose(d.mean(0).numpy(), [0.1, -0.2, 0.0], atol=1e-3)
    np.testing.assert_allclose(d.std(0).numpy(), [0.01, 0.02, 0.03], rtol=0.03)
    o = (noisy.opacity_logits - g.opacity_logits).double()
    assert float(o.mean()) == pytest.approx(-0.3, abs=5e-3) and float(o.std()) == pytest.approx(0.2, rel=0.03)
    assert torch.equal(noisy.sh, g.sh)  # colours are never noised
    assert torch.allclose(noisy.quats, g.normalized_quats(), atol=1e-6)  # zero rotation noise: same rotation


def test_pair_schedule_is_algorithm_1():
    rng = np.random.default_rng(0)
    s = PairSchedule(p0=1.0, decay=0.995)
    kinds = [s.draw(rng) for _ in range(2000)]
    n_noise = kinds.count("noise")
    assert kinds[0] == "noise" and s.noise_used == n_noise
    assert s.p == pytest.approx(0.995**n_noise)
    assert 0 < kinds.count("loo") < 2000
    early, late = kinds[:100].count("noise"), kinds[-500:].count("noise")
    assert early > 65 and late < 60  # noise pairs give way to leave-one-out pairs (p = 0.995^k)
    # replaying from a saved state gives the same draws
    s2 = PairSchedule(p0=0.5, decay=0.995)  # the saved state replaces p
    s2.load_state(s.state())
    r1, r2 = np.random.default_rng(5), np.random.default_rng(5)
    assert [s.draw(r1) for _ in range(50)] == [s2.draw(r2) for _ in range(50)]
    only_noise = PairSchedule(p0=1.0, decay=0.995, has_loo_pairs=False)
    assert all(only_noise.draw(rng) == "noise" for _ in range(100))
