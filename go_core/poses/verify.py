"""Is a set of camera poses plausible for an object capture? Checks that need no ground truth.

Used to verify estimated poses (``poses --estimate``) before anyone builds a hull on them, and by the pose
check as evidence that needs no texture:

* **rotation spread**: the largest angle between two cameras' optical axes. Photos of an object from
  around it span tens of degrees; an estimate whose cameras all look the same way (< ``min_spread_deg``)
  is what SfM returns when the matches lie on a static background (a turntable capture: the object turns,
  the room does not);
* **reprojection error** of the reconstruction's points, and how many points each image observes;
* **mask consistency**: the visual hull of the masks must be non-empty and must project onto each mask.
  For every view, rays through its mask pixels are marched through the hull's bounding box; the
  *coverage* is the fraction of them that meet the hull of the OTHER views (a point on such a ray projects
  inside this view's mask by construction, so this is also the fraction of the mask covered by the
  projection of the whole hull). With consistent poses and masks it is close to 1; a camera turned by a
  few degrees, or poses that do not fit the object, leave parts of some masks uncovered.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from go_core.camera import Camera
from go_core.coarse.hull import hull_bounds
from go_core.errors import EmptyHullError
from go_core.seeding import numpy_rng

MIN_SPREAD_DEG = 15.0  # 4 photos around an object span ~90-180°; a static-background estimate ~1°
MIN_COVERAGE = 0.95  # dev + real train views: correct poses >= 0.995, one camera turned 5° <= 0.89
MAX_REPROJ_PX = 2.0  # mean reprojection error for a 256-px image (scaled with the image size)
MIN_OBSERVATIONS = 20  # 3D points seen by each registered image


def optical_axis_angles(cameras: list[Camera]) -> np.ndarray:
    """[n, n] angles (degrees) between the cameras' optical axes."""
    f = np.stack([c.forward / np.linalg.norm(c.forward) for c in cameras])
    return np.degrees(np.arccos(np.clip(f @ f.T, -1.0, 1.0)))


def rotation_spread_deg(cameras: list[Camera]) -> float:
    """The largest angle between two cameras' optical axes (0 for one camera)."""
    return float(optical_axis_angles(cameras).max()) if len(cameras) > 1 else 0.0


def mask_coverage(
    cameras: list[Camera],
    masks: list[np.ndarray],
    *,
    threshold: float = 0.5,
    samples_per_ray: int = 192,
    max_pixels: int = 3000,
    erode_px: int = 1,
    seed: int = 0,
) -> list[float]:
    """Per view, the fraction of its mask pixels whose ray meets the visual hull of the other views
    (``go_core.poses.coverage``, with hard masks: a mask value > ``threshold`` is inside).

    ``max_pixels`` mask pixels per view are drawn (seeded) after eroding the mask by ``erode_px`` (rays
    through the very rim can slip between samples of a thin hull). Raises ``EmptyHullError`` when the
    masks' frusta have no common point at all."""
    import cv2
    import torch

    from go_core.poses.coverage import hard_occupancy, ray_coverage

    masks = [np.asarray(m, np.float32) for m in masks]
    box = hull_bounds(cameras, masks, min_views=len(cameras), threshold=threshold)
    rng = numpy_rng(seed)
    coverage = []
    for i, (cam, mask) in enumerate(zip(cameras, masks, strict=True)):
        m = (mask > threshold).astype(np.uint8)
        if erode_px > 0:
            eroded = cv2.erode(m, np.ones((2 * erode_px + 1,) * 2, np.uint8))
            m = eroded if eroded.any() else m
        rows, cols = np.nonzero(m)
        if rows.size == 0:
            coverage.append(0.0)
            continue
        pick = rng.choice(rows.size, min(max_pixels, rows.size), replace=False)
        pix = np.stack([cols[pick] + 0.5, rows[pick] + 0.5, np.ones(pick.size)], 1)
        R = cam.world_to_cam[:3, :3]
        dirs = pix @ np.linalg.inv(cam.K).T @ R  # camera rays rotated to world: (R^T d)^T = d^T R
        dirs = torch.from_numpy(dirs / np.linalg.norm(dirs, axis=1, keepdims=True))
        others = [j for j in range(len(cameras)) if j != i]
        occupancy = hard_occupancy([cameras[j] for j in others], [masks[j] for j in others], threshold)
        center = torch.from_numpy(cam.center)
        chunk = max(1, 400_000 // samples_per_ray)  # rays per call: bounds the points held at once
        hit = torch.cat(
            [
                ray_coverage(center, dirs[k : k + chunk], box, samples_per_ray, occupancy)
                for k in range(0, len(dirs), chunk)
            ]
        )
        coverage.append(float(hit.mean()))
    return coverage


@dataclass
class PoseVerdict:
    """What the plausibility checks found; ``problems`` is empty when the poses pass."""

    num_views: int
    rotation_spread_deg: float
    mean_reprojection_px: float | None = None
    min_observations: int | None = None
    mask_coverage: dict[str, float] | None = None  # None: no masks to check with
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def to_dict(self) -> dict:
        d = asdict(self)
        d["ok"] = self.ok
        return d


def verify_poses(
    cameras: list[Camera],
    masks: list[np.ndarray] | None,
    *,
    mean_reprojection_px: float | None = None,
    observations: dict[str, int] | None = None,
    min_spread_deg: float = MIN_SPREAD_DEG,
    min_coverage: float = MIN_COVERAGE,
    max_reprojection_px: float = MAX_REPROJ_PX,
    min_observations: int = MIN_OBSERVATIONS,
    reference_size: int = 256,
) -> PoseVerdict:
    """Run every check that the inputs allow; each failure adds one sentence to ``problems``."""
    verdict = PoseVerdict(len(cameras), rotation_spread_deg(cameras))
    if len(cameras) >= 2 and verdict.rotation_spread_deg < min_spread_deg:
        verdict.problems.append(
            f"the cameras' viewing directions span only {verdict.rotation_spread_deg:.1f}° "
            f"(< {min_spread_deg:g}°): views of an object from around it differ by tens of degrees. "
            "SfM returns this when the matches lie on a static background (the object turned on a "
            "turntable): give images with an alpha mask, or masks, so only the object is matched"
        )
    if mean_reprojection_px is not None:
        size = max(max(c.width, c.height) for c in cameras)
        limit = max_reprojection_px * size / reference_size
        verdict.mean_reprojection_px = float(mean_reprojection_px)
        if not np.isfinite(mean_reprojection_px) or mean_reprojection_px > limit:
            verdict.problems.append(
                f"mean reprojection error {mean_reprojection_px:.2f} px > {limit:.2f} px: the "
                "reconstruction does not fit its own matches"
            )
    if observations is not None:
        verdict.min_observations = min(observations.values()) if observations else 0
        few = [f"{n} ({k})" for n, k in observations.items() if k < min_observations]
        if few:
            verdict.problems.append(
                f"too few reconstructed points seen by {', '.join(few)} (< {min_observations}): "
                "its pose rests on too little evidence"
            )
    if masks is None:
        verdict.notes.append("mask consistency not checked: the images have no masks")
    elif len(cameras) >= 2:
        try:
            cov = mask_coverage(cameras, masks)
        except EmptyHullError:
            verdict.mask_coverage = {c.name: 0.0 for c in cameras}
            verdict.problems.append(
                "the visual hull of the masks is empty under these poses: the masks' frusta do not meet"
            )
        else:
            verdict.mask_coverage = {c.name: v for c, v in zip(cameras, cov, strict=True)}
            low = [f"{c.name} {v:.2f}" for c, v in zip(cameras, cov, strict=True) if v < min_coverage]
            if low:
                verdict.problems.append(
                    "the masks disagree with the poses: the visual hull of the other views covers only "
                    f"part of the mask of {', '.join(low)} (< {min_coverage:g})"
                )
    return verdict
