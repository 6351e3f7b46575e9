"""Pieces shared by the scene readers: problem collection, pose checks, pixel loading, view choice, resizing.

Readers first describe each view as a ``ViewSpec`` (camera + file paths, no pixels), then ``load_views``
reads the pixels and checks them. Every check reports through a ``Problems`` collector: in strict mode
(``load_scene``) the first problem raises ``SceneError``; in collecting mode (``validate_scene``) the readers
carry on past it so that one run lists every problem in the scene.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from go_core.camera import Camera
from go_core.errors import SceneError
from go_core.io.images import ImageReadError, read_image, read_mask, split_rgb_alpha
from go_core.scene.types import View

ORTHONORMAL_TOL = 1e-3  # max |RᵀR − I|; float32-rounded poses are ~1e-7 off
MASK_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff", ".PNG", ".JPG", ".JPEG")


class Problems:
    """Collects scene problems; ``strict`` raises the first one as a ``SceneError`` instead."""

    def __init__(self, strict: bool) -> None:
        self.strict = strict
        self.items: list[SceneError] = []

    def add(self, message: str, path: str | Path | None = None) -> None:
        self.extend(SceneError(message, path=path))

    def extend(self, err: SceneError) -> None:
        if self.strict:
            raise err
        if all(str(e) != str(err) for e in self.items):  # the same line once (e.g. a top-level value)
            self.items.append(err)

    def __len__(self) -> int:
        return len(self.items)

    @property
    def lines(self) -> list[str]:
        return [str(e) for e in self.items]


@dataclass
class Distortion:
    """OpenCV distortion of a COLMAP camera: the image is undistorted to the pinhole ``K`` on read."""

    K: np.ndarray  # the same pinhole K as the view's camera (go_core convention)
    coeffs: np.ndarray  # OpenCV order: k1, k2, p1, p2[, k3, k4, k5, k6]


@dataclass
class ViewSpec:
    """One view before its pixels are read."""

    camera: Camera
    image_path: Path
    mask_path: Path | None = None
    distortion: Distortion | None = None
    where: Path | None = None  # the file that defines this view (for problems about the pose)
    extra: dict = field(default_factory=dict)


def view_name(image_path: Path, root: Path) -> str:
    """A file-system-safe view name: the image path relative to ``root`` without extension, '/' → '_'."""
    try:
        rel = image_path.relative_to(root)
    except ValueError:
        rel = Path(image_path.name)
    return rel.with_suffix("").as_posix().replace("/", "_")


def fmt_num(x: float) -> str:
    return f"{x:.6g}"


def check_intrinsics(values: dict[str, float], problems: Problems, where: Path, label: str = "") -> bool:
    """Finite, positive focal lengths and finite principal point; returns True when all are good."""
    ok = True
    prefix = f"{label}: " if label else ""
    for key, v in values.items():
        if v is None:
            continue
        if not np.isfinite(v):
            problems.add(f"{prefix}intrinsic {key} is {v} (NaN/inf)", where)
            ok = False
        elif key in ("fx", "fy", "fl_x", "fl_y", "f", "width", "height", "w", "h") and v <= 0:
            problems.add(f"{prefix}intrinsic {key} must be positive, got {fmt_num(v)}", where)
            ok = False
    return ok


def check_rigid(M: np.ndarray, problems: Problems, where: Path, label: str) -> bool:
    """A 4x4 rigid transform: finite, last row [0 0 0 1], orthonormal rotation with det +1."""
    if M.shape != (4, 4):
        problems.add(f"{label}: pose must be 4x4, got shape {list(M.shape)}", where)
        return False
    if not np.isfinite(M).all():
        problems.add(f"{label}: pose contains NaN/inf", where)
        return False
    if not np.allclose(M[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        problems.add(f"{label}: pose last row must be [0, 0, 0, 1], got {[fmt_num(x) for x in M[3]]}", where)
        return False
    R = M[:3, :3]
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    if err > ORTHONORMAL_TOL:
        problems.add(f"{label}: rotation is not orthonormal (max |RᵀR − I| = {err:.3g}; scaled?)", where)
        return False
    if np.linalg.det(R) < 0:
        problems.add(f"{label}: rotation has determinant −1 (a reflection, not a rotation)", where)
        return False
    return True


def find_mask_file(candidates: list[Path]) -> Path | None:
    """The first existing file among ``candidates`` (each tried with and without the mask suffixes)."""
    for base in candidates:
        if base.suffix and base.is_file():
            return base
        for suffix in MASK_SUFFIXES:
            p = base.with_name(base.name + suffix)
            if p.is_file():
                return p
    return None


def _undistort(a: np.ndarray, d: Distortion, interpolation: int) -> np.ndarray:
    """Resample a distorted image onto the pinhole camera ``d.K`` (same size).

    OpenCV puts pixel centres at integer coordinates, go_core at +0.5: K is shifted by 0.5 for OpenCV."""
    import cv2

    h, w = a.shape[:2]
    K_cv = d.K.copy()
    K_cv[0, 2] -= 0.5
    K_cv[1, 2] -= 0.5
    map1, map2 = cv2.initUndistortRectifyMap(K_cv, d.coeffs, None, K_cv, (w, h), cv2.CV_32FC1)
    return cv2.remap(a, map1, map2, interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def load_views(specs: list[ViewSpec], problems: Problems) -> list[View]:
    """Read and check the pixels of each view; views with a problem are left out (collecting mode)."""
    import cv2

    views: list[View] = []
    for spec in specs:
        cam = spec.camera
        try:
            pixels = read_image(spec.image_path)
        except ImageReadError as exc:
            problems.extend(exc)
            continue
        if not np.isfinite(pixels).all():
            problems.add("image contains NaN/inf pixel values", spec.image_path)
            continue
        rgb, alpha = split_rgb_alpha(pixels)
        h, w = rgb.shape[:2]
        if (w, h) != (cam.width, cam.height):
            where = spec.where or spec.image_path
            problems.add(
                f"image {spec.image_path.name} is {w}x{h} but its camera says {cam.width}x{cam.height}", where
            )
            continue
        mask, mask_source = alpha, None
        if spec.mask_path is not None:
            try:
                mask = read_mask(spec.mask_path)
            except ImageReadError as exc:
                problems.extend(exc)
                continue
            mh, mw = mask.shape
            if (mw, mh) != (w, h):
                problems.add(f"mask is {mw}x{mh} but image {spec.image_path.name} is {w}x{h}", spec.mask_path)
                continue
            mask_source = spec.mask_path
        if spec.distortion is not None:
            rgb = _undistort(rgb, spec.distortion, cv2.INTER_LINEAR)
            if mask is not None:
                mask = _undistort(mask, spec.distortion, cv2.INTER_LINEAR)
        views.append(View(cam, np.ascontiguousarray(rgb), mask, spec.image_path, mask_source))
    return views


def check_masks(views: list[View], problems: Problems) -> list[View]:
    """Scene-level mask rules.

    * An alpha channel that is fully opaque in EVERY view carries no mask: the masks are dropped (RGBA files
      written by tools that always add alpha).
    * Otherwise each mask must mark some pixels as object and some as background (> 0.5 / ≤ 0.5): an empty
      or all-ones mask is a problem. Masks must be given for all views or for none.
    """
    with_mask = [v for v in views if v.mask is not None]
    if not with_mask:
        return views
    from_alpha = [v for v in with_mask if v.mask_source is None]
    if from_alpha and len(from_alpha) == len(views) and all(float(v.mask.min()) >= 1.0 for v in from_alpha):
        for v in views:
            v.mask = None
        return views
    for v in views:
        where = v.mask_source or v.source
        what = "mask" if v.mask_source is not None else "alpha mask"
        if v.mask is None:
            problems.add(f"no mask for this view while {len(with_mask)} other views have masks", v.source)
            continue
        inside = v.mask > 0.5
        if not inside.any():
            problems.add(f"{what} is empty (no pixel > 0.5)", where)
        elif inside.all():
            problems.add(f"{what} is all ones (covers the whole image)", where)
    return views


def farthest_point_choice(cameras: list[Camera], n: int) -> list[int]:
    """``n`` indices spread over viewing directions: start with camera 0, then repeatedly add the camera whose
    forward direction has the largest angle to its nearest chosen one (ties: lowest index). Sorted."""
    if n >= len(cameras):
        return list(range(len(cameras)))
    dirs = np.stack([c.forward / np.linalg.norm(c.forward) for c in cameras])
    chosen = [0]
    nearest = np.arccos(np.clip(dirs @ dirs[0], -1.0, 1.0))
    while len(chosen) < n:
        nearest_masked = np.round(nearest, 9)  # equal angles up to float noise are ties: lowest index wins
        nearest_masked[chosen] = -1.0
        best = int(np.argmax(nearest_masked))
        chosen.append(best)
        nearest = np.minimum(nearest, np.arccos(np.clip(dirs @ dirs[best], -1.0, 1.0)))
    return sorted(chosen)


def resize_view(view: View, max_size: int) -> View:
    """Downscale (area filter) so the longest side is ≤ ``max_size``; K is scaled per axis by the exact
    size ratio (new_w / w, new_h / h) so pixel-centre coordinates stay consistent."""
    import cv2

    cam = view.camera
    if max_size <= 0 or max(cam.width, cam.height) <= max_size:
        return view
    s = max_size / max(cam.width, cam.height)
    nw, nh = max(1, round(cam.width * s)), max(1, round(cam.height * s))
    K = cam.K.copy()
    K[0] *= nw / cam.width
    K[1] *= nh / cam.height
    new_cam = Camera(cam.name, nw, nh, K, cam.world_to_cam.copy())
    image = cv2.resize(view.image, (nw, nh), interpolation=cv2.INTER_AREA)
    mask = None if view.mask is None else cv2.resize(view.mask, (nw, nh), interpolation=cv2.INTER_AREA)
    return View(new_cam, np.ascontiguousarray(image), mask, view.source, view.mask_source)
