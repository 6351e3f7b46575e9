"""Training-camera poses from silhouette coherence: a texture-free pose pre-alignment for few views.

With correct cameras, the visual hull carved by every other view covers view ``j``'s mask completely when
projected into view ``j`` (a visual hull contains the object). A mis-rotated camera carves away part of the
object, so some of view ``j``'s mask is no longer covered: silhouette coherence (Hernández, Schmitt &
Cipolla, PAMI 2007). The loss is the uncovered share of every mask:

    L = Σ_j  mean over mask_j pixels of  (1 − max_t Π_{i≠j} m_i(π_i(o_j + t d_j)))

with m_i the mask grown by σ and blurred by σ (smooth gradients and a wider basin, while the true cameras
still reach nearly full coverage: a blur alone rewards turning cones away from the mask borders), and the
max over samples along the ray inside the hull's box.

Rotations and centres are corrected. Coverage alone would let a camera move back for free (a farther
camera's cone is fatter and carves less), and with the centres free every similarity of all cameras leaves
the coverage unchanged; both are held by a prior on each centre's move, ``centre_sigma`` × the mean camera
distance (a move of one sigma costs as much as ``PRIOR_WEIGHT`` of a mask left uncovered). On the 5 dev
scenes with every training camera turned 5° and moved 5 % of its distance (256 px images), the mean
reprojection error of the object after the best similarity falls from 24–37 px to 4.5–8.3 px (5.8 px on
average) with the centres free, and only to 7.8–13.3 px (9.8 px) with the centres held
(``centre_sigma = 0``: rotations only); more steps per level let the flat plate drift (8.3 → 11.9 px).

Every camera moves, the first included. Holding one view fixed, as a gauge would be for full poses, keeps
that view's own error, which the others can only partly compensate (with the centres held, on the dev
scenes above: 13–23 px with view 0 fixed, 8–13 px with every view free). An epipolar tangency term
(frontier points: the two planes through a baseline that graze the object must be the extreme epipolar
planes of both masks) was measured as an addition and changed the mean by < 0.1 px, so it is not here.

Four silhouettes leave slack (the hull of three views is looser than the object), so this is a
pre-alignment, not a calibration: the aligned cameras' coverage matches the true cameras' to 0.2 %. The
slack shows from the true cameras too: coverage is already ~0.999 there and Adam's normalised steps wander
along the flat objective, moving the dev scenes' true cameras by 2-18 px (the flat plate most). A prior on
each camera's turn (``rotation_sigma_deg``, off by default) holds them (1°: 0.5-5 px), at the price of
stopping 5° starts nearer where they began (benchmarks/results/pose_refine_dev.md).
~50 CPU s at 256 px, one thread (benchmarks/archive/pose_refine_dev.py, docs/coarse.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from go_core.camera import Camera
from go_core.poses.coverage import ray_coverage
from go_core.poses.refine import PoseCorrection, mean_camera_distance

PRIOR_WEIGHT = 1e-3  # the cost of a move by one sigma (centre or turn), in shares of a mask left uncovered


@dataclass(frozen=True)
class SilhouetteAlignSettings:
    """How the cameras are fitted (the hull step sets ``iterations`` and ``centre_sigma`` from
    ``hull.align_iterations`` and ``hull.align_centre_sigma``)."""

    sizes: tuple[int, ...] = (64, 128)  # longest image side of each coarse-to-fine level
    iterations: int = 80  # Adam steps per level
    samples: int = 64  # samples along each ray inside the box
    blur: float = 1.0  # Gaussian sigma of the masks, in pixels of the level
    lr: float = 3e-3  # radians per step (centres: × the mean camera distance), cosine-decayed ×0.1 per level
    centre_sigma: float = 0.05  # prior on each centre's move, × the mean camera distance; 0: centres held
    rotation_sigma_deg: float = 0.0  # prior on each camera's turn, degrees; 0: none


@dataclass(frozen=True)
class SilhouetteAlignResult:
    cameras: list[Camera]
    rotations_deg: list[float]  # how far each camera was turned
    moved: list[float]  # how far each centre moved, × the mean camera distance
    coverage_before: list[float]  # per view: share of its mask covered by the others' hull
    coverage_after: list[float]


def _blurred(mask: np.ndarray, height: int, width: int, sigma: float) -> torch.Tensor:
    """[1,1,h,w] mask resized (area), grown by σ (so the blur leaves its inside at 1: the true cameras
    reach nearly full coverage) and blurred with a Gaussian of ``sigma`` pixels."""
    m = torch.as_tensor(np.asarray(mask, np.float32))[None, None]
    m = F.interpolate(m, size=(height, width), mode="area")
    if sigma <= 0:
        return m
    grow = max(1, int(math.ceil(sigma)))
    m = F.max_pool2d(m, 2 * grow + 1, stride=1, padding=grow)
    radius = max(1, int(math.ceil(3 * sigma)))
    x = torch.arange(-radius, radius + 1, dtype=torch.float32)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    k = k / k.sum()
    m = F.conv2d(F.pad(m, (radius, radius, 0, 0), mode="replicate"), k.view(1, 1, 1, -1))
    return F.conv2d(F.pad(m, (0, 0, radius, radius), mode="replicate"), k.view(1, 1, -1, 1))


class _Level:
    """The masks and rays of one coarse-to-fine level."""

    def __init__(self, cameras: list[Camera], masks: list[np.ndarray], size: int, blur: float) -> None:
        scale = size / max(cameras[0].width, cameras[0].height)
        self.shapes = [(max(1, round(c.height * scale)), max(1, round(c.width * scale))) for c in cameras]
        self.masks = [_blurred(m, h, w, blur) for m, (h, w) in zip(masks, self.shapes, strict=True)]
        self.sharp = [_blurred(m, h, w, 0.0) for m, (h, w) in zip(masks, self.shapes, strict=True)]
        self.pixels = []  # per view: full-resolution pixel coordinates [R,2] of mask pixels, their weights
        for cam, sharp, (h, w) in zip(cameras, self.sharp, self.shapes, strict=True):
            weight = sharp[0, 0].reshape(-1)
            vv, uu = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
            uv = torch.stack([(uu + 0.5) * cam.width / w, (vv + 0.5) * cam.height / h], -1).reshape(-1, 2)
            keep = weight > 0.05
            self.pixels.append((uv[keep].double(), weight[keep]))


def _rays(viewmat: torch.Tensor, K: np.ndarray, uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """World origin [3] and unit directions [R,3] of the pixels ``uv`` of a world-to-camera ``viewmat``."""
    Kinv = torch.as_tensor(np.linalg.inv(K), dtype=viewmat.dtype)
    d_cam = torch.cat([uv, torch.ones_like(uv[:, :1])], 1) @ Kinv.T
    R, t = viewmat[:3, :3], viewmat[:3, 3]
    d = d_cam @ R  # R^T d_cam per row
    return -(R.T @ t), d / d.norm(dim=1, keepdim=True)


def _sample(mask: torch.Tensor, viewmat: torch.Tensor, K: torch.Tensor, cam: Camera, x: torch.Tensor):
    """Mask values at world points ``x`` [N,3] seen by one camera (0 behind it or outside the image)."""
    pc = x @ viewmat[:3, :3].T + viewmat[:3, 3]
    z = pc[:, 2:3]
    uv = (pc[:, :2] / z.clamp_min(1e-9)) @ K[:2, :2].T + K[:2, 2]
    grid = torch.stack([uv[:, 0] / cam.width * 2 - 1, uv[:, 1] / cam.height * 2 - 1], -1)
    v = F.grid_sample(mask, grid.float()[None, None], align_corners=False, padding_mode="zeros")
    return v[0, 0, 0] * (z[:, 0] > 0)


def coverage(
    cameras: list[Camera],
    viewmats: torch.Tensor,
    level: _Level,
    box: tuple[torch.Tensor, torch.Tensor],
    samples: int,
) -> list[torch.Tensor]:
    """Per view, the weighted mean coverage (``go_core.poses.coverage``) of its mask by the hull of the
    other views' blurred masks (1 = coherent), differentiable in ``viewmats``."""
    Ks = [torch.as_tensor(c.K, dtype=viewmats.dtype) for c in cameras]
    out = []
    for j, cam in enumerate(cameras):
        uv, weight = level.pixels[j]
        origin, dirs = _rays(viewmats[j], cam.K, uv.to(viewmats.dtype))

        def occupancy(x: torch.Tensor, j: int = j) -> torch.Tensor:
            product = torch.ones(len(x), dtype=torch.float32)
            for i, other in enumerate(cameras):
                if i != j:
                    product = product * _sample(level.masks[i], viewmats[i], Ks[i], other, x)
            return product

        covered = ray_coverage(origin, dirs, box, samples, occupancy)
        out.append((covered * weight).sum() / weight.sum().clamp_min(1e-9))
    return out


def align_cameras(
    cameras: list[Camera],
    masks: list[np.ndarray],
    box: tuple[np.ndarray, np.ndarray],
    settings: SilhouetteAlignSettings = SilhouetteAlignSettings(),
) -> SilhouetteAlignResult:
    """Turn (and with ``settings.centre_sigma`` > 0 move) every camera so the masks agree (module docstring).
    ``box`` (lo, hi) bounds the object (e.g. ``go_core.coarse.hull.hull_bounds`` with every view but one)."""
    if len(cameras) < 3:
        raise ValueError(f"silhouette coherence needs at least 3 views, got {len(cameras)}")
    dtype = torch.float64
    base = torch.stack([c.viewmat_tensor(dtype=dtype) for c in cameras])
    lo, hi = (torch.as_tensor(np.asarray(b, np.float64)) for b in box)
    pad = 0.25 * (hi - lo)  # room for the hull to move while the cameras turn
    box_t = (lo - pad, hi + pad)
    corr = PoseCorrection(len(cameras), dtype=dtype)  # every view moves (module docstring)
    distance = mean_camera_distance(cameras)
    groups = [{"params": [corr.rotation], "lr": settings.lr, "base_lr": settings.lr}]
    if settings.centre_sigma > 0:
        lr = settings.lr * distance
        groups.append({"params": [corr.translation], "lr": lr, "base_lr": lr})
    else:
        corr.translation.requires_grad_(False)
    optimizer = torch.optim.Adam(groups)
    levels = [_Level(cameras, masks, s, settings.blur) for s in settings.sizes]
    with torch.no_grad():
        before = [float(c) for c in coverage(cameras, base, levels[-1], box_t, settings.samples)]
    for level in levels:
        for it in range(settings.iterations):
            decay = 0.1 + 0.9 * 0.5 * (1.0 + math.cos(math.pi * it / settings.iterations))
            for group in optimizer.param_groups:
                group["lr"] = group["base_lr"] * decay
            cover = coverage(cameras, corr(base), level, box_t, settings.samples)
            loss = sum(1.0 - c for c in cover) / len(cover)
            if settings.centre_sigma > 0:  # |τ| is the centre's move (camera-side correction)
                moved = corr.translation / (settings.centre_sigma * distance)
                loss = loss + PRIOR_WEIGHT * moved.pow(2).sum(1).mean()
            if settings.rotation_sigma_deg > 0:  # |ω| is the camera's turn
                turn = corr.rotation / math.radians(settings.rotation_sigma_deg)
                loss = loss + PRIOR_WEIGHT * turn.pow(2).sum(1).mean()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
    aligned = corr.apply_to(cameras)
    with torch.no_grad():
        after = [float(c) for c in coverage(cameras, corr(base), levels[-1], box_t, settings.samples)]
        turned = [float(np.degrees(np.linalg.norm(r))) for r in corr.rotation.numpy()]
        moved = [float(np.linalg.norm(t)) / distance for t in corr.translation.numpy()]
    return SilhouetteAlignResult(aligned, turned, moved, before, after)
