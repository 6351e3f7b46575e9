"""NeRF-synthetic / Blender scenes: ``transforms_train.json`` (required) and ``transforms_test.json``.

Intrinsics (top level, or per frame overriding the top level): ``fl_x``/``fl_y`` in pixels, else
``camera_angle_x`` (→ ``fl_x = w / (2 tan(angle_x / 2))``) and ``camera_angle_y`` (→ ``fl_y``; else
``fl_y = fl_x``); ``cx``/``cy`` default to ``w/2``/``h/2``; ``w``/``h`` default to the first image's size.
Poses are OpenGL camera-to-world matrices, converted with ``Camera.from_opengl_c2w``.

``file_path`` is relative to the scene folder; without an extension the first existing of
``go_core.io.images.IMAGE_EXTENSIONS`` (.png first) is used. Masks: an explicit mask file wins, searched as
``masks/<file_path>.*`` (mirroring the image path, e.g. ``masks/train/r_0.png``), then ``masks/<stem>.*``,
then ``<image dir>/<stem>_mask.*``; otherwise an RGBA image's alpha is the mask.
``transforms_val.json`` is ignored (it duplicates the test split in NeRF-synthetic).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from go_core.camera import Camera
from go_core.io.images import IMAGE_EXTENSIONS, ImageReadError, image_size
from go_core.scene.common import (
    Problems,
    ViewSpec,
    check_intrinsics,
    check_rigid,
    find_mask_file,
    view_name,
)

TRAIN_FILE = "transforms_train.json"
TEST_FILE = "transforms_test.json"
_INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y")


def is_nerf_scene(root: Path) -> bool:
    return (root / TRAIN_FILE).is_file() or (root / TEST_FILE).is_file()


def _resolve_image(root: Path, file_path: str) -> tuple[Path | None, Path]:
    """(existing image path or None, the base path tried)."""
    rel = file_path[2:] if file_path.startswith("./") else file_path
    base = root / rel
    if base.suffix in IMAGE_EXTENSIONS and base.is_file():
        return base, base
    for ext in IMAGE_EXTENSIONS:
        p = base.with_name(base.name + ext)
        if p.is_file():
            return p, base
    return None, base


def _mask_candidates(root: Path, image: Path) -> list[Path]:
    try:
        rel_noext = image.relative_to(root).with_suffix("")
    except ValueError:
        rel_noext = Path(image.stem)
    return [root / "masks" / rel_noext, root / "masks" / image.stem, image.parent / f"{image.stem}_mask"]


def _number(value, key: str, problems: Problems, where: Path) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        problems.add(f"intrinsic {key} must be a number, got {value!r}", where)
        return None
    return float(value)


def _intrinsics(
    top: dict, frame: dict, image: Path | None, problems: Problems, where: Path, label: str
) -> tuple[int, int, np.ndarray] | None:
    """(width, height, K) for one frame, or None after reporting a problem. Problems with top-level values
    carry no frame label, so that ``Problems`` reports them once per file rather than once per frame."""
    own = any(k in frame for k in _INTRINSIC_KEYS)
    label = label if own else ""
    vals = {}
    for k in _INTRINSIC_KEYS:
        src = frame if k in frame else top
        vals[k] = _number(src.get(k), k, problems, where)
    if not check_intrinsics(vals, problems, where, label):
        return None
    w, h = vals["w"], vals["h"]
    if w is None or h is None:
        if image is None:
            return None  # the missing image is reported by the caller
        try:
            iw, ih, _ = image_size(image)
        except ImageReadError as exc:
            problems.extend(exc)
            return None
        w = iw if w is None else w
        h = ih if h is None else h
    fx, fy = vals["fl_x"], vals["fl_y"]
    ax, ay = vals["camera_angle_x"], vals["camera_angle_y"]
    for key, angle in (("camera_angle_x", ax), ("camera_angle_y", ay)):
        if angle is not None and not 0.0 < angle < math.pi:
            prefix = f"{label}: " if label else ""
            problems.add(f"{prefix}{key} must be in (0, π) radians, got {angle:.6g}", where)
            return None
    if fx is None:
        if ax is None:
            prefix = f"{label}: " if label else ""
            problems.add(f"{prefix}no focal length (need fl_x or camera_angle_x)", where)
            return None
        fx = 0.5 * w / math.tan(0.5 * ax)
    if fy is None:
        fy = 0.5 * h / math.tan(0.5 * ay) if ay is not None else fx
    cx = vals["cx"] if vals["cx"] is not None else w / 2.0
    cy = vals["cy"] if vals["cy"] is not None else h / 2.0
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return int(round(w)), int(round(h)), K


def _read_json(path: Path, problems: Problems) -> dict | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        problems.add(f"invalid JSON (line {exc.lineno} column {exc.colno}: {exc.msg})", path)
        return None
    except (OSError, UnicodeDecodeError) as exc:
        problems.add(f"unreadable file ({exc})", path)
        return None
    if not isinstance(data, dict):
        problems.add("top level must be a JSON object", path)
        return None
    if not isinstance(data.get("frames"), list):
        problems.add("no 'frames' list", path)
        return None
    return data


def read_nerf_split(root: Path, file_name: str, problems: Problems) -> list[ViewSpec]:
    """ViewSpecs of one transforms file (no pixels read except headers when w/h are not given)."""
    path = root / file_name
    data = _read_json(path, problems)
    if data is None:
        return []
    specs: list[ViewSpec] = []
    for i, frame in enumerate(data["frames"]):
        label = f"frame {i}"
        if not isinstance(frame, dict) or not isinstance(frame.get("file_path"), str):
            problems.add(f"{label}: missing 'file_path'", path)
            continue
        fp = frame["file_path"]
        label = f"frame {i} ({fp})"
        image, base = _resolve_image(root, fp)
        if image is None:
            if base.suffix in IMAGE_EXTENSIONS:
                problems.add(f"image not found (referenced by {file_name} {label})", base)
            else:
                also = ", ".join(IMAGE_EXTENSIONS[1:4])
                where = base.with_name(base.name + IMAGE_EXTENSIONS[0])
                problems.add(f"image not found (referenced by {file_name} {label}; also tried {also})", where)
        try:
            c2w = np.asarray(frame.get("transform_matrix"), dtype=np.float64)
        except (TypeError, ValueError):
            problems.add(f"{label}: transform_matrix is not a 4x4 matrix of numbers", path)
            continue
        pose_ok = check_rigid(c2w, problems, path, label)
        intr = _intrinsics(data, frame, image, problems, path, label)
        if image is None or intr is None or not pose_ok:
            continue
        w, h, K = intr
        cam = Camera.from_opengl_c2w(view_name(image, root), w, h, K, c2w)
        mask = find_mask_file(_mask_candidates(root, image))
        specs.append(ViewSpec(cam, image, mask, where=path))
    return specs


def read_nerf_specs(root: Path, problems: Problems) -> tuple[list[ViewSpec], list[ViewSpec]]:
    """(train specs, test specs); a missing transforms_test.json gives no test views."""
    train: list[ViewSpec] = []
    if not (root / TRAIN_FILE).is_file():
        problems.add(f"missing {TRAIN_FILE} (NeRF-synthetic scenes need it)", root / TRAIN_FILE)
    else:
        train = read_nerf_split(root, TRAIN_FILE, problems)
    test = read_nerf_split(root, TEST_FILE, problems) if (root / TEST_FILE).is_file() else []
    return train, test
