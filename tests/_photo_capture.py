"""A synthetic photo capture for the photo-folder tests: a textured sphere ray-cast (exactly, in float64) from
cameras on a ring around it, saved as RGBA PNGs whose alpha is the sphere's silhouette, with the true cameras.

The texture is value noise on a 3D grid (fixed seed per object): dense, high-contrast blobs that SIFT finds
from every side, so SfM must register every view."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from go_core.camera import Camera, look_at
from go_core.io.images import write_png


def _noise_colour(points: np.ndarray, seed: int, cells: int = 40) -> np.ndarray:
    """Trilinear value noise in [0, 1]^3 at ``points`` [N, 3] inside the unit ball."""
    grid = np.random.default_rng(seed).random((cells + 1, cells + 1, cells + 1, 3))
    u = (points + 1.0) / 2.0 * cells
    i = np.clip(np.floor(u).astype(int), 0, cells - 1)
    f = u - i
    out = np.zeros((len(points), 3))
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                w = (f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1])
                w = w * (f[:, 2] if dz else 1 - f[:, 2])
                out += w[:, None] * grid[i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz]
    return np.clip((out - 0.5) * 2.2 + 0.5, 0.0, 1.0)


def ring_cameras(n: int, size: int = 256, elevation_deg: float = 20.0, distance: float = 3.2) -> list[Camera]:
    """``n`` cameras evenly spaced in azimuth, looking at the origin (+Z up)."""
    cams = []
    el = np.radians(elevation_deg)
    for k in range(n):
        az = 2 * np.pi * k / n
        eye = distance * np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
        f = 1.4 * size
        K = np.array([[f, 0.0, size / 2], [0.0, f, size / 2], [0.0, 0.0, 1.0]])
        cams.append(look_at(f"v{k:02d}", eye, np.zeros(3), np.array([0.0, 0.0, 1.0]), K, size, size))
    return cams


def render_sphere(cam: Camera, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(RGB [H, W, 3] on grey, silhouette [H, W]) of the unit sphere seen by ``cam``."""
    h, w = cam.height, cam.width
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    pix = np.stack([xs.ravel(), ys.ravel(), np.ones(h * w)], 1)
    dirs = pix @ np.linalg.inv(cam.K).T @ cam.world_to_cam[:3, :3]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    o = cam.center
    b = dirs @ o
    disc = b**2 - (o @ o - 1.0)
    hit = disc > 0
    t = -b[hit] - np.sqrt(disc[hit])
    p = o + t[:, None] * dirs[hit]
    shade = 0.55 + 0.45 * np.clip(p @ np.array([0.3, 0.2, 0.93]), 0, 1)
    rgb = np.full((h * w, 3), 0.5)
    rgb[hit] = _noise_colour(p, seed) * shade[:, None]
    return rgb.reshape(h, w, 3).astype(np.float32), hit.reshape(h, w).astype(np.float32)


def write_capture(folder: Path, n: int = 16, seed: int = 0, prefix: str = "IMG_", size: int = 256) -> list:
    """RGBA PNGs ``prefix0000.png``... of the sphere from ``n`` ring cameras; returns the cameras."""
    folder.mkdir(parents=True, exist_ok=True)
    cams = ring_cameras(n, size)
    for k, cam in enumerate(cams):
        rgb, mask = render_sphere(cam, seed)
        write_png(folder / f"{prefix}{k:04d}.png", np.concatenate([rgb, mask[..., None]], 2))
    return cams
