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


def camera_path_cameras(
    train_cameras: list[Camera], frames_per_segment: int, max_size: int = 0
) -> list[Camera]:
    """A closed path through the TRAINING cameras (in their order around the fitted ellipse), like
    nerfstudio's interpolated camera path: between consecutive cameras the viewing direction is slerped, the
    position moves on a sphere-like arc around the look-at point (direction slerped, distance interpolated),
    ``frames_per_segment`` frames per pair; intrinsics of the first camera (longest side at most ``max_size``
    when > 0)."""
    from scipy.spatial.transform import Rotation, Slerp

    if frames_per_segment < 1:
        raise ValueError("a camera path needs at least one frame per segment")
    if len(train_cameras) < 2:
        raise ValueError("a camera path needs at least 2 cameras")
    like = train_cameras[0]
    if max_size and max(like.width, like.height) > max_size:
        like = like.scaled(max_size / max(like.width, like.height))
    ellipse = fit_ellipse(train_cameras)
    angles = [float(ellipse.angle_of(c.center)[0]) for c in train_cameras]
    start = float(angles[0])
    order = sorted(range(len(train_cameras)), key=lambda i: (angles[i] - start) % (2 * np.pi))
    cams = [train_cameras[i] for i in order]
    target = ellipse.target
    out: list[Camera] = []
    for k, (a, b) in enumerate(zip(cams, cams[1:] + cams[:1], strict=True)):
        rots = Rotation.from_matrix(np.stack([a.cam_to_world[:3, :3], b.cam_to_world[:3, :3]]))
        slerp = Slerp([0.0, 1.0], rots)
        da, db = a.center - target, b.center - target
        ra, rb = float(np.linalg.norm(da)), float(np.linalg.norm(db))
        ua, ub = da / ra, db / rb
        omega = float(np.arccos(np.clip(ua @ ub, -1.0, 1.0)))
        for j in range(frames_per_segment):
            t = j / frames_per_segment
            if omega < 1e-6:
                u = ua
            else:
                u = (np.sin((1 - t) * omega) * ua + np.sin(t * omega) * ub) / np.sin(omega)
            centre = target + u * ((1 - t) * ra + t * rb)
            c2w = np.eye(4)
            c2w[:3, :3] = slerp([t]).as_matrix()[0]
            c2w[:3, 3] = centre
            name = f"path_{k * frames_per_segment + j:03d}"
            out.append(Camera(name, like.width, like.height, like.K.copy(), np.linalg.inv(c2w)))
    return out
