"""Analytic depth maps of a sphere and an axis-aligned cube (ray casting) for the TSDF tests."""

from __future__ import annotations

import numpy as np

from go_core.camera import Camera, look_at
from go_core.mesh.views import fibonacci_directions


def ring_cameras(count: int = 8, size: int = 96, distance: float = 3.2, elevation_deg: float = 20.0):
    """``count`` cameras on a ring around the origin (+Z up), 40° horizontal field of view."""
    f = size / (2 * np.tan(np.radians(20.0)))
    K = np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]])
    el = np.radians(elevation_deg)
    cams = []
    for k in range(count):
        az = 2 * np.pi * k / count
        pos = distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        cams.append(look_at(f"ring_{k}", pos, np.zeros(3), np.array([0, 0, 1.0]), K, size, size))
    return cams


def sphere_cameras_around(count: int, like: Camera, distance: float = 3.2) -> list[Camera]:
    return [
        look_at(f"s{k}", distance * d, np.zeros(3), np.array([0, 0, 1.0]), like.K, like.width, like.height)
        for k, d in enumerate(fibonacci_directions(count))
    ]


def _rays(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    j, i = np.mgrid[0 : cam.height, 0 : cam.width]
    pix = np.stack([i + 0.5, j + 0.5, np.ones_like(i, dtype=np.float64)], -1).reshape(-1, 3)
    d_cam = pix @ np.linalg.inv(cam.K).T  # z = 1 in the camera frame
    R = cam.world_to_cam[:3, :3]
    return np.broadcast_to(cam.center, d_cam.shape), d_cam @ R  # world directions with unit camera-z


def sphere_depth(cam: Camera, radius: float, back: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(camera-z depth, alpha) [H,W] of a sphere of ``radius`` at the origin: where each ray enters it, or
    leaves it (``back``)."""
    o, d = _rays(cam)
    a, b, c = (d * d).sum(1), 2 * (o * d).sum(1), (o * o).sum(1) - radius**2
    disc = b * b - 4 * a * c
    hit = disc >= 0
    root = np.sqrt(np.maximum(disc, 0))
    t = np.where(hit, (-b + (root if back else -root)) / (2 * a), 0.0)
    return t.reshape(cam.height, cam.width), hit.reshape(cam.height, cam.width).astype(np.float32)


def cube_depth(cam: Camera, half: float) -> tuple[np.ndarray, np.ndarray]:
    """(camera-z depth, alpha) [H,W] of the cube [-half, half]^3 (slab intersection)."""
    o, d = _rays(cam)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-half - o) / d, (half - o) / d
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    hit = (tmax >= tmin) & (tmax > 0)
    return np.where(hit, tmin, 0.0).reshape(cam.height, cam.width), hit.reshape(cam.height, cam.width).astype(
        np.float32
    )


def box_mesh(half: float):
    """The cube [-half, half]^3 as 12 outward-facing triangles."""
    from go_core.mesh.types import TriMesh

    v = np.array([[x, y, z] for x in (-half, half) for y in (-half, half) for z in (-half, half)], np.float64)
    f = [
        [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
        [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],
    ]  # fmt: skip
    mesh = TriMesh(v, np.array(f, np.int64))
    if mesh.volume() < 0:
        mesh.faces = mesh.faces[:, ::-1].copy()
    return mesh
