"""Distance-aware repair views (arcs of the training-camera ellipse), λ(π), w(t) and the L_rep decay."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from go_core.camera import look_at, raise_towards
from go_core.repair.arcs import RepairArcs, with_raised_twins
from go_core.repair.loss import repair_image_loss
from go_core.repair.weights import distance_weight, dreamfusion_weight, lrep_decay, neighbour_dmax

K = np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])


def ring_cameras(azimuths_deg, elevation_deg=20.0, radius=3.2, prefix="train"):
    cams = []
    for i, az in enumerate(np.radians(azimuths_deg)):
        el = np.radians(elevation_deg)
        pos = radius * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        cams.append(look_at(f"{prefix}_{i}", pos, np.zeros(3), np.array([0, 0, 1.0]), K, 100, 100))
    return cams


def test_views_lie_on_middle_80_percent_of_arcs():
    train = ring_cameras([30, 120, 250, 300])  # uneven gaps: arcs of 90, 130, 50, 90 degrees
    arcs = RepairArcs.from_cameras(train, keep=0.8)
    assert len(arcs) == 4
    lengths = sorted(round(np.degrees(arcs.arc_bounds(i)[1])) for i in range(4))
    assert lengths == [50, 90, 90, 130]
    views = arcs.sample(np.random.default_rng(0), per_arc=200)
    assert len(views) == 800
    refs = arcs.reference_positions()
    for v in views:
        arc, frac = arcs.arc_position(v.theta)
        assert arc == v.arc and 0.1 - 1e-9 <= frac <= 0.9 + 1e-9  # never in the 10% next to a reference
        c = v.camera.center
        assert np.linalg.norm(c - arcs.ellipse.point(v.theta)) < 1e-9  # on the ellipse
        # looks at the look-at centre of the training cameras
        d = arcs.ellipse.target - c
        assert np.dot(v.camera.forward, d / np.linalg.norm(d)) > 1 - 1e-9
        _, length = arcs.arc_bounds(arc)
        chord_min = 2 * 3.2 * np.cos(np.radians(20)) * np.sin(0.1 * length / 2)
        assert np.linalg.norm(refs - c, axis=1).min() >= chord_min - 1e-6
    fracs = np.array([arcs.arc_position(v.theta)[1] for v in views])
    assert fracs.min() < 0.12 and fracs.max() > 0.88  # the whole middle part is used


def elevation_deg(position: np.ndarray) -> float:
    return float(np.degrees(np.arcsin(position[2] / np.linalg.norm(position))))


def test_lifted_views_are_raised_twins():
    """repair.lift_deg adds after each view its twin at the same azimuth and distance, that many degrees
    higher, looking at the target; the base views are those drawn without it."""
    train = ring_cameras([30, 120, 210, 300])  # 20 degrees above the target, radius 3.2
    arcs = RepairArcs.from_cameras(train, keep=0.8)
    base = arcs.sample(np.random.default_rng(3), per_arc=2)
    lifted = with_raised_twins(arcs.sample(np.random.default_rng(3), per_arc=2), arcs.ellipse, 30.0)
    assert len(lifted) == 2 * len(base)
    assert [v.camera.name for v in lifted[::2]] == [v.camera.name for v in base]
    for b, v, up in zip(base, lifted[::2], lifted[1::2], strict=True):
        np.testing.assert_allclose(v.camera.center, b.camera.center, atol=1e-12)
        assert (up.arc, up.theta) == (b.arc, b.theta) and up.camera.name == b.camera.name + "_up"
        c, u = b.camera.center, up.camera.center
        assert np.linalg.norm(u) == pytest.approx(np.linalg.norm(c), abs=1e-9)
        assert elevation_deg(u) == pytest.approx(elevation_deg(c) + 30.0, abs=1e-6)
        assert np.degrees(np.arctan2(u[1], u[0])) == pytest.approx(
            np.degrees(np.arctan2(c[1], c[0])), abs=1e-6
        )
        assert np.dot(up.camera.forward, -u / np.linalg.norm(u)) > 1 - 1e-9  # looks at the target


def test_raise_towards_stops_below_the_pole():
    target, up = np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.0, 2.0])
    raised = raise_towards(target + np.array([2.0, 0.0, 0.0]), target, up, 120.0)
    assert elevation_deg(raised - target) == pytest.approx(89.0, abs=1e-9)
    with pytest.raises(ValueError, match="up axis"):
        raise_towards(target + np.array([0.0, 0.0, 2.0]), target, up, 10.0)


def test_arcs_depend_on_training_cameras_only():
    train = ring_cameras([30, 120, 210, 300])
    a = RepairArcs.from_cameras(train, keep=0.8).sample(np.random.default_rng(1), per_arc=2)
    b = RepairArcs.from_cameras(list(train), keep=0.8).sample(np.random.default_rng(1), per_arc=2)
    assert [v.theta for v in a] == [v.theta for v in b]
    test = ring_cameras([0, 75, 165, 255], elevation_deg=45, prefix="test")
    test_centres = np.stack([c.center for c in test])
    for v in a:
        assert np.linalg.norm(test_centres - v.camera.center, axis=1).min() > 0.1
        assert not v.camera.name.startswith("test")


def test_lambda_matches_formula():
    refs = np.array([[0.0, 0, 0], [2.0, 0, 0], [2.0, 3.0, 0], [0.0, 3.0, 0]])
    d_max = neighbour_dmax(refs)
    assert d_max == pytest.approx(3.0)  # largest distance between neighbouring references
    pos = np.array([1.0, 1.0, 0.0])
    expected = 2.0 * min(np.linalg.norm(pos - r) for r in refs) / 3.0
    assert distance_weight(pos, refs, d_max) == pytest.approx(expected) == pytest.approx(2 * np.sqrt(2) / 3)
    assert distance_weight(refs[2], refs, d_max) == 0.0
    assert distance_weight(np.array([2.0, 1.5, 0]), refs, d_max) == pytest.approx(1.0)  # mid of longest gap


def test_dreamfusion_weight_matches_sd_schedule():
    from diffusers import DDIMScheduler

    from go_core.diffusion.configs import SD15_SCHEDULER

    ac = DDIMScheduler(**SD15_SCHEDULER).alphas_cumprod
    betas = np.linspace(np.sqrt(0.00085), np.sqrt(0.012), 1000) ** 2
    alpha_bar = np.cumprod(1.0 - betas)
    for t in (0, 1, 281, 500, 999):
        assert dreamfusion_weight(ac, t) == pytest.approx(1.0 - alpha_bar[t], rel=1e-5, abs=1e-7)
    assert dreamfusion_weight(alpha_bar, 981) == pytest.approx(1.0 - alpha_bar[981])


def test_lrep_decay_and_loss():
    assert lrep_decay(0, 2800) == 1.0 and lrep_decay(2799, 2800) == pytest.approx(0.1)
    assert lrep_decay(1400, 2800) == pytest.approx(1.0 - 0.9 * 1400 / 2799)
    assert lrep_decay(2800, 2800) == 0.0 and lrep_decay(3999, 2800) == 0.0
    a = torch.zeros(1, 3, 4, 4)
    b = torch.full((1, 3, 4, 4), 0.5)
    assert float(repair_image_loss(a, b)) == pytest.approx(0.5 + 0.25)
    assert float(repair_image_loss(a, b, lpips=lambda x, y: torch.tensor([2.0]))) == pytest.approx(2.75)
