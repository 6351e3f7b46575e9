"""Feature matches that disagree with the poses against the silhouettes (go_core.poses.silhouettes), and
DISK's sub-pixel keypoints (go_core.features.disk.subpixel_peaks).

The object is analytic (two ellipsoids, exact masks), so the true cameras are known: matches made with a
wrongly turned camera (a symmetric object matched to itself) ask for a turn the masks refute; matches of
a camera whose *given* pose is turned ask for the turn back, which the masks accept."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from _ellipsoids import ellipsoid_mask, ring_cameras, turned

from go_core.features.disk import strict_maxima, subpixel_peaks
from go_core.poses.refine import rotation_angle_deg
from go_core.poses.silhouettes import lowest_coverage, pair_turns, refutation_floor, turn_to_matches
from go_core.poses.verify import MIN_COVERAGE


@pytest.fixture(scope="module")
def scene():
    truth = ring_cameras(8)  # 45° apart: neighbours share most of the object
    return truth, [ellipsoid_mask(c) for c in truth]


def _surface_points(count: int, seed: int) -> np.ndarray:
    """Points on the first ellipsoid (centre 0, semi-axes 0.5, 0.3, 0.7)."""
    d = np.random.default_rng(seed).normal(size=(count, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True) * np.array([0.5, 0.3, 0.7])


def _matches(cam_i, cam_j, points):
    """Pixels of ``points`` in both views, kept where both see them in front and inside the image."""
    (xi, zi), (xj, zj) = cam_i.project(points), cam_j.project(points)
    ok = (zi > 0) & (zj > 0) & np.all((xi > 0) & (xi < 64) & (xj > 0) & (xj < 64), axis=1)
    return xi[ok], xj[ok]


def test_turn_to_matches_recovers_a_planted_turn(scene):
    truth, _ = scene
    given = turned(truth[1], 3.0, np.random.default_rng(0))
    xi, xj = _matches(truth[0], truth[1], _surface_points(300, 1))  # the photos agree with the truth
    cam, degrees, epipolar = turn_to_matches((truth[0], given), (xi, xj), 1, 1.0)
    assert abs(degrees - 3.0) < 0.3  # the turn back; a roll about the baseline is not observable
    assert epipolar < 0.05
    assert rotation_angle_deg(cam.world_to_cam, truth[1].world_to_cam) < rotation_angle_deg(
        given.world_to_cam, truth[1].world_to_cam
    )


def _floor(cameras, masks) -> float:
    return refutation_floor(lowest_coverage(cameras, masks), MIN_COVERAGE)


def _self_matches(truth, i: int, j: int, degrees: float, seed: int):
    """Matches as a symmetric object makes them: consistent with view j turned ``degrees``, not the truth."""
    ghost = turned(truth[j], degrees, np.random.default_rng(seed))
    return _matches(truth[i], ghost, _surface_points(300, seed + 1))


def test_self_matches_of_a_correct_pair_are_refuted_by_the_silhouettes(scene):
    truth, masks = scene
    assert lowest_coverage(truth, masks) >= MIN_COVERAGE  # the masks agree with the true poses
    turns = pair_turns(truth, masks, (0, 1), _self_matches(truth, 0, 1, 25.0, 2), 1.5, _floor(truth, masks))
    assert turns.refuted(_floor(truth, masks)), turns
    assert min(turns.turn_deg) > 10.0
    assert max(turns.coverage) < MIN_COVERAGE


def test_matches_of_a_turned_camera_ask_for_a_turn_the_silhouettes_accept(scene):
    truth, masks = scene
    given = list(truth)
    given[1] = turned(truth[1], 2.0, np.random.default_rng(4))  # its photo was taken from the truth
    xi, xj = _matches(truth[0], truth[1], _surface_points(300, 5))
    floor = _floor(given, masks)
    turns = pair_turns(given, masks, (0, 1), (xi, xj), 1.5, floor)
    assert not turns.refuted(floor), turns
    assert 1.0 < max(turns.turn_deg) < 4.0
    # with that camera wrong, self-matches elsewhere are still refuted (the floor follows the given poses)
    turns = pair_turns(given, masks, (4, 5), _self_matches(truth, 4, 5, 25.0, 6), 1.5, floor)
    assert turns.refuted(floor), turns


def test_subpixel_peaks_find_the_vertex_of_a_sampled_parabola():
    yy, xx = torch.meshgrid(torch.arange(16.0), torch.arange(20.0), indexing="ij")
    peaks = torch.tensor([[4.3, 6.8], [11.0, 13.0], [9.6, 3.45]])  # (x, y)
    heat = torch.zeros(16, 20)
    for x0, y0 in peaks:  # separable paraboloid bumps: the 3-point fit is exact on each axis
        bump = 1.0 - 0.2 * ((xx - x0) ** 2 + (yy - y0) ** 2)
        heat = torch.maximum(heat, bump)
    yx = strict_maxima(heat, window=5).nonzero()
    xy = subpixel_peaks(heat, yx)
    order = torch.argsort(xy[:, 0])
    torch.testing.assert_close(xy[order], peaks[torch.argsort(peaks[:, 0])], atol=1e-5, rtol=0)


def test_subpixel_peaks_on_the_border_plateaus_and_flat_ridges():
    heat = torch.zeros(8, 8)
    heat[0, 3] = 1.0  # top row: no neighbour above, stays on its row
    heat[5, 5] = heat[5, 6] = 1.0  # a two-pixel plateau along x: its midpoint
    heat[2, 1:4] = 1.0  # a flat ridge of three along x: no curvature, stays put
    xy = subpixel_peaks(heat, torch.tensor([[0, 3], [5, 5], [2, 2]]))
    torch.testing.assert_close(xy, torch.tensor([[3.0, 0.0], [5.5, 5.0], [2.0, 2.0]]))
