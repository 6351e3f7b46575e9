"""Camera paths for visualisation: a turntable on the ellipse fitted to the TRAINING cameras only.

(The reference code fits its path to all cameras, test views included, which leaks test poses into the
training-side outputs; here test cameras never shape a path.)
"""

from __future__ import annotations

import numpy as np

from go_core.camera import Camera, fit_ellipse


def turntable_cameras(train_cameras: list[Camera], frames: int, max_size: int = 0) -> list[Camera]:
    """``frames`` cameras evenly spaced in angle on the fitted ellipse, starting at the first training
    camera's angle, looking at the common look-at point, with the first camera's intrinsics (rescaled so the
    longest side is at most ``max_size`` when > 0)."""
    if frames < 1:
        raise ValueError("a turntable needs at least one frame")
    like = train_cameras[0]
    if max_size and max(like.width, like.height) > max_size:
        like = like.scaled(max_size / max(like.width, like.height))
    ellipse = fit_ellipse(train_cameras)
    theta0 = float(ellipse.angle_of(train_cameras[0].center)[0])
    thetas = theta0 + 2.0 * np.pi * np.arange(frames) / frames
    return [ellipse.camera(f"turntable_{i:03d}", float(t), like) for i, t in enumerate(thetas)]


def contact_sheet(frames: list[np.ndarray], count: int, columns: int = 4, pad: int = 2) -> np.ndarray:
    """uint8 grid of ``count`` frames evenly picked from ``frames`` (white padding)."""
    idx = np.unique(np.linspace(0, len(frames) - 1, min(count, len(frames))).round().astype(int))
    pick = [frames[i] for i in idx]
    h, w = pick[0].shape[:2]
    cols = min(columns, len(pick))
    rows = (len(pick) + cols - 1) // cols
    sheet = np.full((rows * (h + pad) + pad, cols * (w + pad) + pad, 3), 255, np.uint8)
    for k, img in enumerate(pick):
        r, c = divmod(k, cols)
        y, x = pad + r * (h + pad), pad + c * (w + pad)
        sheet[y : y + h, x : x + w] = img
    return sheet
