"""Similarity transforms between camera frames: the first stage of evaluating a pose-refined (CF) model.

A model fitted with refined training cameras lives in the frame of those cameras; the given test cameras
live in the frame of the given training cameras. ``similarity_from_cameras`` finds the similarity
x' = s·R·x + t that maps the given training camera centres onto the refined ones (Umeyama's least-squares
solution, float64), and ``Similarity.camera`` maps any camera of the given frame into the refined one.
Fewer than three cameras, or centres on a line, leave the transform undetermined: an error, not a guess.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from go_core.camera import Camera


class AlignmentError(ValueError):
    """The cameras do not determine a similarity transform."""


@dataclass(frozen=True)
class Similarity:
    scale: float
    rotation: np.ndarray  # [3,3]
    translation: np.ndarray  # [3]

    def points(self, x: np.ndarray) -> np.ndarray:
        """Map points [..., 3] of the source frame into the target frame."""
        return self.scale * np.asarray(x, np.float64) @ self.rotation.T + self.translation

    def camera(self, cam: Camera) -> Camera:
        """``cam`` (given frame) as the same physical camera in the target frame: it sees every mapped
        point where it saw the original (world_to_cam' = [R_c Rᵀ | s·t_c − R_c Rᵀ t])."""
        w2c = np.asarray(cam.world_to_cam, np.float64)
        r = w2c[:3, :3] @ self.rotation.T
        out = np.eye(4)
        out[:3, :3] = r
        out[:3, 3] = self.scale * w2c[:3, 3] - r @ self.translation
        return Camera(cam.name, cam.width, cam.height, cam.K, out)


def umeyama(src: np.ndarray, dst: np.ndarray) -> Similarity:
    """The least-squares similarity mapping points ``src`` [N,3] onto ``dst`` [N,3] (Umeyama 1991)."""
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise AlignmentError(f"need two [N,3] point sets of one shape, got {src.shape} and {dst.shape}")
    if len(src) < 3:
        raise AlignmentError(f"a similarity needs at least 3 cameras, got {len(src)}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = float((xs**2).sum() / len(src))
    sv = np.linalg.svd(xs, compute_uv=False)
    if var_s <= 0 or sv[1] < 1e-9 * max(sv[0], 1e-300):
        raise AlignmentError(
            "the camera centres are (nearly) on a line: the rotation about it is undetermined"
        )
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    fix = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        fix[2, 2] = -1.0
    rotation = u @ fix @ vt
    scale = float(np.trace(np.diag(d) @ fix) / var_s)
    return Similarity(scale, rotation, mu_d - scale * rotation @ mu_s)


def similarity_from_cameras(given: list[Camera], refined: list[Camera]) -> Similarity:
    """The similarity taking the ``given`` cameras' centres onto the ``refined`` ones."""
    if len(given) != len(refined):
        raise AlignmentError(f"{len(given)} given cameras but {len(refined)} refined ones")
    return umeyama(np.stack([c.center for c in given]), np.stack([c.center for c in refined]))
