"""Auto masks for photos without alpha: the u2netp salient-object model (``salient_weights``) and the
post-processing chosen by measured IoU on ``photos/ethiopian_head`` (benchmarks/photo_masks.py,
docs/photo_masks.md).

Public API (used by the ``mask`` step and by the photo-folder path):

* ``load_segmenter()``: the u2netp model from the weights cache (one MissingWeightsError naming the file
  when it is missing or corrupt);
* ``auto_mask(image, segmenter, settings, box)``: one RGB photo (uint8 [H,W,3], or float in [0, 1]) → mask
  float32 [H,W] in {0, 1}; ``box`` (optional, x0,y0,x1,y1 pixels) says where the object is in this photo.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from go_core.scene.mask_post import Box, box_mask, fill_holes, grabcut_refine, largest_component
from go_core.scene.masking import OnnxSegmenter
from go_core.scene.object_hint import ObjectBox

HINT_WIDEN = 0.1  # a carried box grows by this fraction of its size on each side
HULL_VOTE = 0.95  # hull_vote_masks: a voxel stays when this share of the views that see it mask it
VOTE_MIN_VIEWS = 8  # the vote needs this many posed views to outvote a wrong mask


@dataclass(frozen=True)
class AutoMaskSettings:
    """How a saliency map becomes a mask (the ``mask`` step's ``auto_*`` params)."""

    threshold: float = 0.5  # saliency above this is the object
    crop_margin: float = 0.08  # second pass on a square crop around the first mask, this much wider (<0: off)
    largest_component: bool = True  # keep only the biggest 8-connected region
    fill_holes: bool = True  # fill background regions enclosed by the object
    refine: str = "none"  # "grabcut": GrabCut seeded by the saliency map (see mask_post.grabcut_refine)


def load_segmenter(root: Path | None = None, threads: int = 2) -> OnnxSegmenter:
    """The u2netp model from the weights cache, SHA-256 checked."""
    from go_core.scene.salient_weights import check_u2netp

    return OnnxSegmenter(check_u2netp(root), "imagenet", threads=threads)


def bounding_box(mask: np.ndarray) -> Box | None:
    """(x0, y0, x1, y1) of a bool mask's True pixels (x1, y1 exclusive); None when it is empty."""
    ys, xs = np.nonzero(mask)
    if ys.size == 0:
        return None
    return float(xs.min()), float(ys.min()), float(xs.max() + 1), float(ys.max() + 1)


def square_crop(box: Box, margin: float, shape: tuple[int, int]) -> tuple[int, int, int, int]:
    """The square (x0, y0, x1, y1) around ``box``, ``margin`` × its longer side wider on each side, shifted
    (and shrunk) to fit an image of ``shape`` (H, W)."""
    h, w = shape
    x0, y0, x1, y1 = box
    side = int(round(min(max(x1 - x0, y1 - y0) * (1.0 + 2.0 * margin), h, w)))
    cx, cy = (x0 + x1) / 2.0, (y0 + y1) / 2.0
    left = int(round(min(max(cx - side / 2.0, 0.0), w - side)))
    top = int(round(min(max(cy - side / 2.0, 0.0), h - side)))
    return left, top, left + side, top + side


def saliency(
    image: np.ndarray, segmenter: OnnxSegmenter, settings: AutoMaskSettings, box: Box | None = None
) -> np.ndarray:
    """Saliency [H,W] in [0, 1]. The model sees the whole photo at its input size; then (``crop_margin``
    ≥ 0) a square crop around the first pass's largest region, or around ``box`` when one is given (the
    model then never sees the whole photo), which shows the object at a higher resolution. Zero outside
    the crop."""
    shape = image.shape[:2]
    if box is None:
        first = segmenter(image)
        if settings.crop_margin < 0:
            return first
        box = bounding_box(largest_component(first > settings.threshold))
        if box is None:
            return first
    x0, y0, x1, y1 = square_crop(box, max(settings.crop_margin, 0.0), shape)
    out = np.zeros(shape, np.float32)
    out[y0:y1, x0:x1] = segmenter(image[y0:y1, x0:x1])
    return out


def auto_mask(
    image: np.ndarray,
    segmenter: OnnxSegmenter,
    settings: AutoMaskSettings = AutoMaskSettings(),
    box: Box | None = None,
) -> np.ndarray:
    """The object mask float32 [H,W] in {0, 1} of one RGB photo; ``box``: the object's region in it."""
    sal = saliency(image, segmenter, settings, box)
    outside = None if box is None else ~box_mask(sal.shape, box)
    if outside is not None:
        sal = np.where(outside, 0.0, sal).astype(np.float32)
    if settings.refine == "grabcut":
        mask = grabcut_refine(image, sal, outside=outside)
    elif settings.refine == "none":
        mask = sal > settings.threshold
    else:
        raise ValueError(f"refine must be 'none' or 'grabcut', got {settings.refine!r}")
    if settings.largest_component:
        mask = largest_component(mask)
    if settings.fill_holes:
        mask = fill_holes(mask)
    return mask.astype(np.float32)


def widen_box(box: Box, fraction: float) -> Box:
    """``box`` grown by ``fraction`` of its width/height on each side."""
    x0, y0, x1, y1 = box
    dx, dy = (x1 - x0) * fraction, (y1 - y0) * fraction
    return x0 - dx, y0 - dy, x1 + dx, y1 + dy


def carry_box(
    hint: ObjectBox, ref_shape: tuple[int, int], shapes: list[tuple[int, int]], widen: float = HINT_WIDEN
) -> list[Box]:
    """The box drawn on the photo of ``ref_shape`` (H, W, as the pipeline holds it) carried to photos of
    ``shapes`` without poses: the same place relative to each image's size (a turntable, or a photographer
    who keeps the object framed alike), ``widen`` × its size wider on each side, since the object's outline
    changes from view to view."""
    h, w = ref_shape
    x0, y0, x1, y1 = hint.pixels(w, h)
    out = []
    for vh, vw in shapes:
        sx, sy = vw / w, vh / h
        out.append(widen_box((x0 * sx, y0 * sy, x1 * sx, y1 * sy), widen))
    return out


def box_region(box: Box, ref, cameras: list) -> np.ndarray:
    """The box drawn on camera ``ref``'s image as a 3D region: the box's frustum between the depths
    ``z ± r`` in ``ref``, where z is the depth of the point closest to every camera's optical axis (the
    object's centre for a capture around it) and r half the box's longer side at that depth (an object
    about as deep as it is wide). Returns its 8 corners [8,3] in world coordinates."""
    from go_core.camera import look_at_point

    centre = look_at_point(cameras)
    z = float((ref.world_to_cam[:3, :3] @ centre + ref.world_to_cam[:3, 3])[2])
    if z <= 0:
        raise ValueError(f"the cameras' common centre is behind {ref.name}")
    x0, y0, x1, y1 = box
    r = 0.5 * max(x1 - x0, y1 - y0) / float(ref.K[0, 0]) * z
    pix = np.array([[x, y, 1.0] for x in (x0, x1) for y in (y0, y1)])
    rays = pix @ np.linalg.inv(ref.K).T  # camera-frame points at depth 1
    local = np.concatenate([rays * (z - r), rays * (z + r)])
    c2w = ref.cam_to_world
    return local @ c2w[:3, :3].T + c2w[:3, 3]


def carry_box_with_poses(box: Box, ref, cameras: list, widen: float = HINT_WIDEN) -> list[Box | None]:
    """The box drawn on camera ``ref``'s image carried to ``cameras`` through their poses: the bounding
    box of the projected 3D region (``box_region``), ``widen`` × its size wider on each side; None for a
    camera that sees part of the region from behind (no box: that view is masked without the hint)."""
    corners = box_region(box, ref, cameras)
    out: list[Box | None] = []
    for cam in cameras:
        uv, depth = cam.project(corners)
        if (depth <= 0).any():
            out.append(None)
            continue
        out.append(widen_box((uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()), widen))
    return out


def hull_vote_voxels(
    masks: list[np.ndarray],
    cameras: list,
    vote: float = HULL_VOTE,
    resolution: int = 96,
    threshold: float = 0.5,
) -> tuple[np.ndarray, float]:
    """(voxel centres [N, 3], voxel size): the voxels that at least ``vote`` of the views seeing them put
    inside their masks (a visual hull that tolerates a few wrong masks). Raises ``EmptyHullError`` when the
    masks agree on no region."""
    import math

    from go_core.coarse.hull import hull_bounds, inside_masks

    need = max(1, math.ceil(vote * len(cameras)))
    lo, hi = hull_bounds(cameras, masks, min_views=need, threshold=threshold)
    axes = [np.linspace(lo[k], hi[k], resolution) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    inside = inside_masks(grid, cameras, masks, threshold).sum(0)
    seen = np.zeros(len(grid))
    for cam in cameras:
        uv, z = cam.project(grid)
        seen += (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    kept = grid[(inside >= vote * seen) & (seen > 0)]
    return kept, float(np.max((hi - lo) / (resolution - 1)))


def hull_vote_masks(
    masks: list[np.ndarray],
    cameras: list,
    vote: float = HULL_VOTE,
    resolution: int = 96,
    threshold: float = 0.5,
) -> list[np.ndarray]:
    """Masks made consistent through the poses: each mask ∩ the projection of the ``hull_vote_voxels``. What
    one view's salient-object map wrongly takes in (a turntable disc, a stand) is carved away by the views
    that leave it out. Returns float32 {0, 1} masks, largest component, holes filled."""
    kept, voxel = hull_vote_voxels(masks, cameras, vote, resolution, threshold)
    regions = [_splat(cam, kept, voxel) for cam in cameras]
    return [
        fill_holes(largest_component((mask > threshold) & region)).astype(np.float32)
        for mask, region in zip(masks, regions, strict=True)
    ]


def _splat(cam, points: np.ndarray, voxel: float) -> np.ndarray:
    """Bool [H,W]: the pixels ``points`` (voxel centres) cover, each grown to its voxel's footprint."""
    import cv2

    region = np.zeros((cam.height, cam.width), np.uint8)
    uv, z = cam.project(points)
    ok = (z > 0) & np.isfinite(uv).all(1)
    cols, rows = np.round(uv[ok, 0]).astype(int), np.round(uv[ok, 1]).astype(int)
    inside = (cols >= 0) & (cols < cam.width) & (rows >= 0) & (rows < cam.height)
    region[rows[inside], cols[inside]] = 1
    if not inside.any():
        return region.astype(bool)
    r = int(np.ceil(float(cam.K[0, 0]) * voxel / float(np.median(z[ok])))) + 1
    return cv2.dilate(region, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))) > 0
