"""Similarity alignment of camera frames (CF evaluation, stage 1) on planted transforms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from go_core.camera import Camera, look_at
from go_core.poses.similarity import AlignmentError, Similarity, similarity_from_cameras, umeyama


def _cameras(n: int, seed: int = 0) -> list[Camera]:
    rng = np.random.default_rng(seed)
    K = np.array([[80.0, 0, 32], [0, 80.0, 32], [0, 0, 1]])
    cams = []
    for i in range(n):
        d = rng.normal(size=3)
        cams.append(
            look_at(f"c{i}", 3.0 * d / np.linalg.norm(d), np.zeros(3), np.array([0, 0, 1.0]), K, 64, 64)
        )
    return cams


def _project(cam: Camera, x: np.ndarray) -> np.ndarray:
    p = x @ cam.world_to_cam[:3, :3].T + cam.world_to_cam[:3, 3]
    uv = p @ cam.K.T
    return uv[:, :2] / uv[:, 2:]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_planted_similarity_is_recovered_and_cameras_see_the_same_pixels(seed):
    rng = np.random.default_rng(100 + seed)
    planted = Similarity(
        float(rng.uniform(0.3, 3.0)), Rotation.random(random_state=seed).as_matrix(), rng.normal(size=3)
    )
    given = _cameras(4, seed)
    refined = [planted.camera(c) for c in given]
    found = similarity_from_cameras(given, refined)
    assert found.scale == pytest.approx(planted.scale, rel=1e-10)
    np.testing.assert_allclose(found.rotation, planted.rotation, atol=1e-10)
    np.testing.assert_allclose(found.translation, planted.translation, atol=1e-9)
    # a mapped camera sees mapped points at the same pixels (the check that the camera maths is right)
    points = rng.normal(size=(20, 3)) * 0.3
    for cam in _cameras(3, seed + 10):
        np.testing.assert_allclose(
            _project(found.camera(cam), found.points(points)), _project(cam, points), atol=1e-8
        )


def test_noisy_centres_give_the_least_squares_answer():
    rng = np.random.default_rng(7)
    src = rng.normal(size=(8, 3))
    rot = Rotation.from_euler("xyz", [10, -20, 30], degrees=True).as_matrix()
    dst = 2.0 * src @ rot.T + np.array([1.0, 2.0, 3.0]) + rng.normal(scale=1e-3, size=(8, 3))
    s = umeyama(src, dst)
    assert s.scale == pytest.approx(2.0, abs=5e-3)
    assert np.degrees(np.arccos((np.trace(s.rotation @ rot.T) - 1) / 2)) < 0.2


def test_undetermined_alignments_are_errors():
    cams = _cameras(2)
    with pytest.raises(AlignmentError, match="at least 3"):
        similarity_from_cameras(cams, cams)
    line = np.array([[0.0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3]])
    with pytest.raises(AlignmentError, match="on a line"):
        umeyama(line, line)
    with pytest.raises(AlignmentError, match="given cameras"):
        similarity_from_cameras(_cameras(4), _cameras(3))
