"""An analytic object for silhouette tests: two overlapping ellipsoids whose exact masks are ray/ellipsoid
intersections, seen by cameras on a ring (no tests here)."""

from __future__ import annotations

import numpy as np

from go_core.camera import Camera, look_at

SIZE = 64
# an asymmetric object: two overlapping ellipsoids (centre, semi-axes)
ELLIPSOIDS = [
    (np.array([0.0, 0.0, 0.0]), np.array([0.5, 0.3, 0.7])),
    (np.array([0.3, 0.2, 0.3]), np.array([0.25, 0.45, 0.2])),
]


def ellipsoid_mask(cam: Camera) -> np.ndarray:
    """Exact silhouette: pixels whose ray (through the pixel centre) hits an ellipsoid."""
    v, u = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    d_cam = np.stack([u, v, np.ones_like(u)], -1).reshape(-1, 3) @ np.linalg.inv(cam.K).T
    R, t = cam.world_to_cam[:3, :3], cam.world_to_cam[:3, 3]
    d = d_cam @ R
    o = -R.T @ t
    hit = np.zeros(len(d), bool)
    for c, axes in ELLIPSOIDS:
        oo, dd = (o - c) / axes, d / axes
        a, b, cc = (dd * dd).sum(1), 2 * (dd @ oo), oo @ oo - 1.0
        hit |= b * b - 4 * a * cc >= 0
    return hit.reshape(SIZE, SIZE).astype(np.float32)


def ring_cameras(count: int) -> list[Camera]:
    """``count`` cameras on a ring 4 units out, at alternating heights, looking at the origin."""
    f = SIZE / (2 * np.tan(np.radians(20)))
    K = np.array([[f, 0, SIZE / 2], [0, f, SIZE / 2], [0, 0, 1.0]])
    cams = []
    for k in range(count):
        a = 2 * np.pi * k / count
        pos = 4.0 * np.array([np.cos(a), np.sin(a), 0.35 + 0.3 * (k % 2)])
        cams.append(look_at(f"v{k}", pos, np.zeros(3), np.array([0, 0, 1.0]), K, SIZE, SIZE))
    return cams


def turned(cam: Camera, degrees: float, rng: np.random.Generator) -> Camera:
    """``cam`` turned by ``degrees`` about a random axis through its own centre."""
    axis = rng.normal(size=3)
    return cam.turned(np.radians(degrees) * axis / np.linalg.norm(axis))
