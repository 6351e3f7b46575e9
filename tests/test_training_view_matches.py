"""benchmarks/training_view_matches.py's judge of a match, on a cube seen by two cameras 90° apart: exact
matches of surface points are right; matches moved along the epipolar line (the wrong matches LightGlue
makes between wide-baseline views: they pass two-view verification) or off it are wrong."""

from __future__ import annotations

import numpy as np
import pytest
from _benchmark_module import benchmark_module
from _ellipsoids import ring_cameras
from scipy.spatial import cKDTree

from go_core.poses.epipolar import epipolar_distances, fundamental_from_poses

HALF = 0.5  # the cube's half size


def _cube() -> tuple[np.ndarray, np.ndarray]:
    corners = np.array([[x, y, z] for x in (-HALF, HALF) for y in (-HALF, HALF) for z in (-HALF, HALF)])
    quads = [(0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5)]
    faces = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    return corners.astype(np.float64), faces


@pytest.fixture(scope="module")
def bench():
    return benchmark_module("training_view_matches")


def test_surface_samples_lie_on_the_faces_spread_by_area(bench):
    vertices, faces = _cube()
    points = bench.surface_samples(vertices, faces, 60_000, seed=3)
    assert np.allclose(np.abs(points).max(1), HALF)  # every sample on the cube's surface
    # uniform by area: each of the 6 faces gets a sixth (binomial sd ~0.0015)
    axis = np.argmax(np.abs(points), axis=1)
    face = 2 * axis + (points[np.arange(len(points)), axis] > 0)
    share = np.bincount(face, minlength=6) / len(points)
    assert np.allclose(share, 1 / 6, atol=0.008), share
    # a stretched mesh: a triangle 3x the area of another gets 3x the samples
    tri_v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1.5, 0, 1], [0, 2, 1]], np.float64)
    on_big = bench.surface_samples(tri_v, np.array([[0, 1, 2], [3, 4, 5]]), 40_000)[:, 2] > 0.5
    assert abs(on_big.mean() - 0.75) < 0.01


def test_right_and_wrong_matches_on_a_cube(bench):
    vertices, faces = _cube()
    samples = bench.surface_samples(vertices, faces, 200_000, seed=0)
    tree, diag = cKDTree(samples), float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    cams = ring_cameras(4)[:2]  # 90° apart, as the dev scenes' adjacent training views
    points = bench.surface_samples(vertices, faces, 1000, seed=2)
    xy0, xy1 = cams[0].project(points)[0], cams[1].project(points)[0]
    right = bench.right_matches(cams, xy0, xy1, tree, diag, px=3.0, surface=0.02)
    assert right.all()

    # along the epipolar line: the point moved 0.3 deeper along view 0's ray; keep those whose moved
    # point is well inside the cube (> 0.1 from every face), so the match is wrong in 3D
    ray = points - cams[0].center
    deeper = points + 0.3 * ray / np.linalg.norm(ray, axis=1, keepdims=True)
    inside = HALF - np.abs(deeper).max(1) > 0.1
    assert inside.sum() > 60
    moved = cams[1].project(deeper[inside])[0]
    # it passes two-view verification
    assert epipolar_distances(cams[0], cams[1], xy0[inside], moved).max() < 1e-6
    assert not bench.right_matches(cams, xy0[inside], moved, tree, diag, px=3.0, surface=0.02).any()

    # off the epipolar line by 8 px (perpendicular to it): the two rays miss each other, and the point
    # between them reprojects more than 3 px from one of the keypoints
    lines = np.c_[xy0, np.ones(len(xy0))] @ fundamental_from_poses(cams[0], cams[1]).T
    normal = lines[:, :2] / np.linalg.norm(lines[:, :2], axis=1, keepdims=True)
    off = xy1 + 8.0 * normal
    assert (epipolar_distances(cams[0], cams[1], xy0, off) > 3.0).all()
    assert not bench.right_matches(cams, xy0, off, tree, diag, px=3.0, surface=0.02).any()
    # and 1 px off it is still right (keypoints are not exact)
    assert bench.right_matches(cams, xy0, xy1 + normal, tree, diag, px=3.0, surface=0.02).all()
