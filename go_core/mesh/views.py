"""Cameras for depth fusion: the ellipse of the training cameras plus a Fibonacci sphere of views.

The ellipse covers what the photos saw; the sphere adds the top, bottom and oblique views that carve the
space the ellipse never looks through. Every camera looks at the training cameras' common look-at point,
from their mean distance, with the first training camera's intrinsics (rescaled to ``max_size``).
"""

from __future__ import annotations

import numpy as np

from go_core.camera import Camera, fit_ellipse, look_at, look_at_point
from go_core.render.trajectory import turntable_cameras


def _resized(like: Camera, max_size: int) -> Camera:
    if max_size and max(like.width, like.height) > max_size:
        return like.scaled(max_size / max(like.width, like.height))
    return like


def fibonacci_directions(count: int) -> np.ndarray:
    """``count`` unit vectors spread evenly over the sphere (golden-angle spiral), [count, 3]."""
    i = np.arange(count, dtype=np.float64) + 0.5
    z = 1.0 - 2.0 * i / count
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, 1.0))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def sphere_cameras(train_cameras: list[Camera], count: int, max_size: int = 0) -> list[Camera]:
    """``count`` cameras on the sphere around the look-at point at the training cameras' mean distance;
    image-up follows the normal of the training cameras' ellipse."""
    if count <= 0:
        return []
    target = look_at_point(train_cameras) if len(train_cameras) > 1 else train_cameras[0].center
    radius = float(np.mean([np.linalg.norm(c.center - target) for c in train_cameras]))
    up = fit_ellipse(train_cameras).normal if len(train_cameras) > 1 else train_cameras[0].up
    like = _resized(train_cameras[0], max_size)
    cams = []
    for k, d in enumerate(fibonacci_directions(count)):
        cams.append(
            look_at(f"sphere_{k:03d}", target + radius * d, target, up, like.K, like.width, like.height)
        )
    return cams


def fusion_cameras(train_cameras: list[Camera], ellipse: int, sphere: int, max_size: int) -> list[Camera]:
    """The training ellipse's ``ellipse`` cameras followed by ``sphere`` cameras on the sphere."""
    ring = turntable_cameras(train_cameras, ellipse, max_size) if ellipse > 0 else []
    return ring + sphere_cameras(train_cameras, sphere, max_size)
