"""Visual hull by rejection sampling (GaussianObject Sec. 3.3), scale-invariant.

1. Coarse pass: the bounding box of the intersection of the mask frusta, found from the cameras alone:
   a cube around the cameras' common look-at point whose size is proportional to the camera distances is
   gridded, carved by the masks, and shrunk to the carved voxels' bounds (a few rounds). Nothing depends on
   the world's units, unlike a fixed cube.
2. Fine pass: points drawn uniformly in that box are kept when they project inside every mask (or all but
   one, ``min_views = n - 1``); the accepted fraction × box volume estimates the hull volume.
3. Colours: the mean of bilinear image samples over the views that see the point (inside their mask).
4. Points → Gaussians: SH DC from colour, isotropic scale from the mean distance to the nearest neighbours,
   identity rotation, constant opacity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from go_core.camera import Camera
from go_core.errors import EmptyHullError
from go_core.gaussians import Gaussians
from go_core.seeding import numpy_rng


@dataclass
class HullResult:
    points: np.ndarray  # [P,3] float64
    colors: np.ndarray  # [P,3] float32 in [0,1]
    bbox_min: np.ndarray
    bbox_max: np.ndarray
    volume: float  # Monte-Carlo estimate of the hull volume (world units³)
    samples: int  # uniform samples drawn in the fine pass
    min_views: int


def bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` [H,W] or [H,W,C] at continuous pixel coordinates ``uv`` [N,2] (u = col,
    v = row, pixel centres at +0.5); coordinates outside are clamped to the border."""
    h, w = image.shape[:2]
    x = np.clip(uv[:, 0] - 0.5, 0.0, w - 1.0)
    y = np.clip(uv[:, 1] - 0.5, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 2) if w > 1 else np.zeros(len(x), np.int64)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2) if h > 1 else np.zeros(len(y), np.int64)
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fx = (x - x0).astype(np.float32)
    fy = (y - y0).astype(np.float32)
    if image.ndim == 3:
        fx, fy = fx[:, None], fy[:, None]
    top = image[y0, x0] * (1 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1 - fx) + image[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def ray_box(origin: np.ndarray, dirs: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Entry and exit distances [N] of rays (``origin`` [3] or [N,3], unit ``dirs`` [N,3]) through the box
    ``lo``..``hi`` (slab method); entry is clamped at 0 and exit < entry where a ray misses."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / dirs
        t0 = (lo - origin) * inv
        t1 = (hi - origin) * inv
    tmin = np.nan_to_num(np.minimum(t0, t1), nan=-np.inf).max(1)
    tmax = np.nan_to_num(np.maximum(t0, t1), nan=np.inf).min(1)
    return np.maximum(tmin, 0.0), tmax


def inside_masks(
    points: np.ndarray, cameras: list[Camera], masks: list[np.ndarray], threshold: float = 0.5
) -> np.ndarray:
    """Boolean [V,N]: point n projects in front of camera v, inside its image, onto mask value > threshold."""
    out = np.zeros((len(cameras), len(points)), dtype=bool)
    for i, (cam, mask) in enumerate(zip(cameras, masks, strict=True)):
        uv, z = cam.project(points)
        ok = (z > 0) & np.isfinite(uv).all(1)
        ok &= (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        idx = np.nonzero(ok)[0]
        if idx.size:
            out[i, idx] = bilinear(mask, uv[idx]) > threshold
    return out


def _check(cameras: list[Camera], masks: list[np.ndarray]) -> None:
    if len(cameras) != len(masks) or not cameras:
        raise ValueError(f"need one mask per camera, got {len(cameras)} cameras and {len(masks)} masks")
    for cam, m in zip(cameras, masks, strict=True):
        if m.shape[:2] != (cam.height, cam.width):
            raise ValueError(f"mask of {cam.name} is {m.shape[:2]}, camera is {cam.height}x{cam.width}")


def _initial_box(
    cameras: list[Camera], masks: list[np.ndarray], threshold: float
) -> tuple[np.ndarray, np.ndarray]:
    origins, dirs, half_angles = [], [], []
    for cam, mask in zip(cameras, masks, strict=True):
        rows, cols = np.nonzero(mask > threshold)
        if rows.size == 0:
            continue
        pix = np.stack([cols + 0.5, rows + 0.5, np.ones(rows.size)], 1)
        rays = pix @ np.linalg.inv(cam.K).T
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        mean = rays.mean(0)
        mean /= np.linalg.norm(mean)
        cos = np.clip(rays @ mean, -1.0, 1.0)
        R = cam.world_to_cam[:3, :3]
        origins.append(cam.center)
        dirs.append(R.T @ mean)
        half_angles.append(float(np.arccos(cos.min())))
    if not origins:
        raise EmptyHullError("the visual hull is empty: every mask is empty")
    if len(origins) == 1:
        target = origins[0] + dirs[0] * 1.0
    else:
        A = np.zeros((3, 3))
        b = np.zeros(3)
        for o, d in zip(origins, dirs, strict=True):
            P = np.eye(3) - np.outer(d, d)
            A += P
            b += P @ o
        target = np.linalg.lstsq(A, b, rcond=None)[0]
    radius = max(
        float(np.linalg.norm(target - o)) * np.tan(min(a, 1.4))
        for o, a in zip(origins, half_angles, strict=True)
    )
    radius = radius if np.isfinite(radius) and radius > 0 else 1.0
    return target - 2.0 * radius, target + 2.0 * radius


def _empty_hull_message(cameras: list[Camera], inside: np.ndarray, min_views: int) -> str:
    """Name the camera(s) whose mask cone misses the region the other cameras' masks agree on: without
    such a camera the hull would not be empty (its pose is wrong, or it looks away)."""
    counts = inside.sum(0)
    missing = []
    for i, cam in enumerate(cameras):
        others = counts - inside[i]
        agreed = others >= max(min_views - 1, 1)
        if agreed.any() and not (inside[i] & agreed).any():
            missing.append(cam.name)
    if missing:
        which = ", ".join(repr(n) for n in missing)
        cones = "cone misses" if len(missing) == 1 else "cones miss"
        return (
            f"the visual hull is empty: the mask {cones} of camera {which} the region the other cameras' "
            "masks agree on; that pose is probably wrong (or the camera looks away)"
        )
    return "the visual hull is empty: the masks do not overlap in 3D, the poses are probably wrong"


def hull_bounds(
    cameras: list[Camera],
    masks: list[np.ndarray],
    *,
    min_views: int,
    threshold: float = 0.5,
    resolution: int = 64,
    rounds: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box containing the carved region. The first cube is centred on the point closest to the
    rays through the masks' centroids, with a size from the masks' angular extents times the camera
    distances (so it is independent of the world's units); carving shrinks it over ``rounds`` passes."""
    lo, hi = _initial_box(cameras, masks, threshold)
    for r in range(rounds):
        for res in (resolution, 2 * resolution) if r == 0 else (resolution,):
            axes = [np.linspace(lo[k], hi[k], res) for k in range(3)]
            grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
            inside = inside_masks(grid, cameras, masks, threshold)
            keep = inside.sum(0) >= min_views
            if keep.any():
                break
        if not keep.any():
            raise EmptyHullError(_empty_hull_message(cameras, inside, min_views))
        step = (hi - lo) / (res - 1)
        pts = grid[keep]
        lo, hi = pts.min(0) - 1.5 * step, pts.max(0) + 1.5 * step
    return lo, hi


def visual_hull(
    cameras: list[Camera],
    masks: list[np.ndarray],
    images: list[np.ndarray] | None = None,
    *,
    num_points: int = 20_000,
    all_but_one: bool,
    threshold: float = 0.5,
    seed: int = 0,
    batch: int = 200_000,
    max_samples: int = 50_000_000,
) -> HullResult:
    """Sample ``num_points`` points uniformly inside the visual hull (see the module docstring)."""
    _check(cameras, masks)
    n = len(cameras)
    min_views = n - 1 if (all_but_one and n > 1) else n
    masks = [np.asarray(m, np.float32) for m in masks]
    lo, hi = hull_bounds(cameras, masks, min_views=min_views, threshold=threshold)
    rng = numpy_rng(seed)
    kept: list[np.ndarray] = []
    got = drawn = 0
    while got < num_points and drawn < max_samples:
        pts = lo + rng.random((batch, 3)) * (hi - lo)
        drawn += batch
        ok = inside_masks(pts, cameras, masks, threshold).sum(0) >= min_views
        kept.append(pts[ok])
        got += int(ok.sum())
    if got == 0:
        raise EmptyHullError(
            "the visual hull is empty: the masks do not overlap in 3D, the poses are probably wrong"
        )
    points = np.concatenate(kept)
    volume = float(np.prod(hi - lo) * got / drawn)
    points = points[:num_points]
    colors = hull_colors(points, cameras, masks, images, threshold) if images is not None else None
    if colors is None:
        colors = np.full((len(points), 3), 0.5, np.float32)
    return HullResult(points, colors, lo, hi, volume, drawn, min_views)


def hull_colors(
    points: np.ndarray,
    cameras: list[Camera],
    masks: list[np.ndarray],
    images: list[np.ndarray],
    threshold: float,
) -> np.ndarray:
    """Mean bilinear colour over the views whose mask contains the point (all views if none does)."""
    seen = inside_masks(points, cameras, masks, threshold)  # [V,N]
    acc = np.zeros((len(points), 3), np.float64)
    acc_all = np.zeros((len(points), 3), np.float64)
    for i, (cam, img) in enumerate(zip(cameras, images, strict=True)):
        uv, _ = cam.project(points)
        uv = np.nan_to_num(uv, nan=0.0, posinf=0.0, neginf=0.0)
        c = bilinear(np.asarray(img, np.float32), uv)
        acc += c * seen[i, :, None]
        acc_all += c
    count = seen.sum(0)[:, None]
    colors = np.where(count > 0, acc / np.maximum(count, 1), acc_all / len(cameras))
    return np.clip(colors, 0.0, 1.0).astype(np.float32)


def points_to_gaussians(
    points: np.ndarray, colors: np.ndarray, *, opacity: float = 0.1, sh_degree: int = 0, neighbours: int = 3
) -> Gaussians:
    """Isotropic Gaussians at the points: scale = mean distance to the ``neighbours`` nearest points."""
    pts = np.asarray(points, np.float64)
    if len(pts) < 2:
        raise EmptyHullError("the visual hull has fewer than 2 points: the masks barely overlap")
    k = min(neighbours, len(pts) - 1)
    dist, _ = cKDTree(pts).query(pts, k=k + 1)
    scale = np.maximum(dist[:, 1:].mean(1), 1e-7)
    return Gaussians.from_points(
        torch.from_numpy(pts.astype(np.float32)),
        torch.from_numpy(np.asarray(colors, np.float32)),
        torch.from_numpy(scale.astype(np.float32)),
        opacity,
        sh_degree,
    )


def random_init(
    bbox_min: np.ndarray, bbox_max: np.ndarray, num_points: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """The vanilla-3DGS ablation: uniform random points (random colours) in a box."""
    rng = numpy_rng(seed)
    pts = bbox_min + rng.random((num_points, 3)) * (bbox_max - bbox_min)
    return pts, rng.random((num_points, 3)).astype(np.float32)
