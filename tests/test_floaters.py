"""Floater elimination: planted outliers go, the object stays; the λe schedules."""

from __future__ import annotations

import numpy as np
import pytest

from go_core.coarse.floaters import FloaterConfig, floater_mask, knn_mean_distance

pytestmark = pytest.mark.usefixtures("single_thread")  # small tensors: one thread is faster


def _object_with_floaters(seed=0, n=3000, n_out=30):
    rng = np.random.default_rng(seed)
    obj = rng.normal(size=(n, 3))
    obj = obj / np.linalg.norm(obj, axis=1, keepdims=True) * rng.uniform(0.0, 1.0, (n, 1)) ** (1 / 3)
    dirs = rng.normal(size=(n_out, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    floaters = dirs * rng.uniform(2.0, 3.0, (n_out, 1))
    return np.concatenate([obj, floaters]), n


@pytest.mark.parametrize("lam", [1.0, 2.33])
def test_planted_outliers_are_removed_and_the_object_kept(lam):
    pts, n = _object_with_floaters()
    remove = floater_mask(pts, lam)
    assert remove[n:].all(), "every planted floater must go"
    assert remove[:n].mean() < 0.02, "the object must stay (at most a few boundary points)"


def test_knn_mean_distance_matches_brute_force():
    rng = np.random.default_rng(1)
    pts = rng.random((200, 3))
    d = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    k = int(np.sqrt(200))
    brute = np.sort(d, axis=1)[:, 1 : k + 1].mean(1)
    assert np.allclose(knn_mean_distance(pts), brute)


def test_schedules_and_due_steps():
    code = FloaterConfig(floater_schedule="code")
    paper = FloaterConfig(floater_schedule="paper")
    assert code.floater_lambda_at(500) == pytest.approx(1.0)
    assert code.floater_lambda_at(6000) == pytest.approx(2.33)
    assert paper.floater_lambda_at(500) == pytest.approx(1.0)
    assert paper.floater_lambda_at(6000) == pytest.approx(0.0)
    assert code.floater_lambda_at(3250) == pytest.approx(1.665)
    assert [s for s in range(1, 10001) if code.floater_due(s)] == list(range(500, 6001, 500))
    assert not FloaterConfig(floaters=False).floater_due(500)
    with pytest.raises(ValueError):
        FloaterConfig(floater_schedule="cosine")


def test_removal_is_capped():
    pts, _ = _object_with_floaters()
    assert floater_mask(pts, -10.0, max_fraction=0.1).sum() == int(0.1 * len(pts))
