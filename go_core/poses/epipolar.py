"""Epipolar geometry of two posed cameras: the fundamental matrix and the distances of matches to their
epipolar lines (used by the pose check and by the silhouette judgement of disagreeing pairs)."""

from __future__ import annotations

import numpy as np

from go_core.camera import Camera


def fundamental_from_poses(ci: Camera, cj: Camera) -> np.ndarray:
    """F with ``x_j^T F x_i = 0`` for the given cameras (pixel coordinates, our convention)."""
    R = cj.world_to_cam[:3, :3] @ ci.world_to_cam[:3, :3].T
    t = cj.world_to_cam[:3, 3] - R @ ci.world_to_cam[:3, 3]
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    return np.linalg.inv(cj.K).T @ (tx @ R) @ np.linalg.inv(ci.K)


def epipolar_distances(ci: Camera, cj: Camera, xi: np.ndarray, xj: np.ndarray) -> np.ndarray:
    """Symmetric point-to-epipolar-line distance (px) of each match under the given poses."""
    F = fundamental_from_poses(ci, cj)
    hi = np.c_[xi, np.ones(len(xi))]
    hj = np.c_[xj, np.ones(len(xj))]
    lj = hi @ F.T  # epipolar lines in image j
    li = hj @ F  # epipolar lines in image i
    num = np.abs(np.sum(lj * hj, axis=1))
    dj = num / (np.linalg.norm(lj[:, :2], axis=1) + 1e-12)
    di = num / (np.linalg.norm(li[:, :2], axis=1) + 1e-12)
    return 0.5 * (di + dj)
