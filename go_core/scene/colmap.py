"""COLMAP scenes: ``sparse/0`` (binary or text model, read with pycolmap), ``images/``, ``masks/``, splits.

* Model: ``sparse/0``, else ``sparse`` itself when it holds ``cameras.bin``/``cameras.txt``. Only registered
  images (with a pose) are used. COLMAP's pixel convention (centre of the top-left pixel at (0.5, 0.5)) and
  world-to-camera poses are go_core's, so K and ``cam_from_world`` are taken as they are.
* Camera models: PINHOLE and SIMPLE_PINHOLE are used directly. SIMPLE_RADIAL, RADIAL, OPENCV and
  FULL_OPENCV are undistorted with OpenCV on read (images and masks, bilinear, same size and the same
  fx/fy/cx/cy; pixels that map outside the photo become 0). Any other model is rejected by name.
* Images: ``images/<name>``. Masks: ``masks/<name>``, ``masks/<name>.png`` (COLMAP's own mask naming), or
  ``masks/<stem>.<ext>`` (matched by file stem); else an RGBA image's alpha.
* Split (GaussianObject layout, files in the scene folder): indices are 0-based into the registered images
  sorted by name. ``sparse_test.txt`` lists the test views. ``views=N`` uses ``sparse_N.txt`` when present,
  else a farthest-point choice on viewing directions among the non-test images. ``views=0`` uses the only
  ``sparse_N.txt`` when exactly one exists, else every non-test image. Without ``sparse_test.txt``, the
  images not used for training become the test views (none when all are used). A training index that is
  also a test index is a problem.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from go_core.camera import Camera
from go_core.scene.common import (
    Distortion,
    Problems,
    ViewSpec,
    check_intrinsics,
    check_rigid,
    farthest_point_choice,
    find_mask_file,
    view_name,
)

PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE")
UNDISTORTED_MODELS = ("SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV")
SUPPORTED_MODELS = PINHOLE_MODELS + UNDISTORTED_MODELS
_SPLIT_RE = re.compile(r"^sparse_(\d+)\.txt$")


def find_model_dir(root: Path) -> Path | None:
    for d in (root / "sparse" / "0", root / "sparse"):
        if (d / "cameras.bin").is_file() or (d / "cameras.txt").is_file():
            return d
    return None


def is_colmap_scene(root: Path) -> bool:
    return (root / "sparse").is_dir()


def _floats(tokens: list[str]) -> list[float] | None:
    try:
        return [float(t) for t in tokens]
    except ValueError:
        return None


def _prescan_text(model: Path, problems: Problems) -> bool:
    """Check a text model line by line so that errors name the camera/image (pycolmap's do not)."""
    import pycolmap

    known = set(pycolmap.CameraModelId.__members__) - {"INVALID"}
    ok = True
    cams = model / "cameras.txt"
    for lineno, line in enumerate(cams.read_text(errors="replace").splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        tok = line.split()
        if len(tok) < 5:
            problems.add(f"line {lineno}: expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...'", cams)
            ok = False
            continue
        if tok[1] not in known:
            problems.add(f"line {lineno}: unknown camera model {tok[1]!r} (camera {tok[0]})", cams)
            ok = False
            continue
        nums = _floats(tok[2:])
        if nums is None:
            problems.add(f"line {lineno}: camera {tok[0]} has a non-numeric size or parameter", cams)
            ok = False
        elif not all(math.isfinite(x) for x in nums):
            problems.add(f"line {lineno}: camera {tok[0]} ({tok[1]}) has NaN/inf parameters", cams)
            ok = False
    imgs = model / "images.txt"
    if not imgs.is_file():
        problems.add("missing images.txt next to cameras.txt", imgs)
        return False
    text_lines = imgs.read_text(errors="replace").splitlines()
    data_lines = [(n, ln) for n, ln in enumerate(text_lines, 1) if not ln.startswith("#")]
    # image records are pairs of lines: the pose line, then the (possibly empty) 2D points line
    for k in range(0, len(data_lines), 2):
        lineno, line = data_lines[k]
        if not line.strip():
            continue
        tok = line.split()
        name = " ".join(tok[9:]) if len(tok) >= 10 else "?"
        nums = _floats(tok[:9]) if len(tok) >= 10 else None
        if nums is None:
            problems.add(f"line {lineno}: expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'", imgs)
            ok = False
        elif not all(math.isfinite(x) for x in nums):
            problems.add(f"line {lineno}: image {name} has NaN/inf in its pose", imgs)
            ok = False
        elif np.linalg.norm(nums[1:5]) < 1e-12:
            problems.add(f"line {lineno}: image {name} has a zero quaternion", imgs)
            ok = False
    return ok


def _read_split_file(path: Path, count: int, problems: Problems) -> list[int] | None:
    tokens = path.read_text(errors="replace").split()
    try:
        idx = [int(t) for t in tokens]
    except ValueError:
        problems.add("split file must hold whitespace-separated integer indices", path)
        return None
    bad = [i for i in idx if not 0 <= i < count]
    if bad:
        problems.add(f"split indices {bad} out of range: {count} registered images (0-{count - 1})", path)
        return None
    dup = sorted({i for i in idx if idx.count(i) > 1})
    if dup:
        problems.add(f"split indices {dup} are listed more than once", path)
        return None
    return sorted(idx)


def split_files(root: Path) -> dict[int, Path]:
    """{N: sparse_N.txt} in the scene folder."""
    out = {}
    for p in root.glob("sparse_*.txt"):
        m = _SPLIT_RE.match(p.name)
        if m:
            out[int(m.group(1))] = p
    return dict(sorted(out.items()))


def _camera_parts(cam, problems: Problems, where: Path) -> tuple[np.ndarray, Distortion | None] | None:
    model = cam.model_name
    p = np.asarray(cam.params, np.float64)
    label = f"camera {cam.camera_id} ({model})"
    if model not in SUPPORTED_MODELS:
        problems.add(
            f"{label}: unsupported camera model {model} (supported: {', '.join(SUPPORTED_MODELS)})", where
        )
        return None
    if not np.isfinite(p).all():
        problems.add(f"{label}: NaN/inf in camera parameters", where)
        return None
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy = p[1], p[2]
    else:
        fx, fy, cx, cy = p[:4]
    if not check_intrinsics(
        {"fx": fx, "fy": fy, "width": cam.width, "height": cam.height}, problems, where, label
    ):
        return None
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    coeffs = {
        "SIMPLE_RADIAL": lambda: [p[3], 0.0, 0.0, 0.0],
        "RADIAL": lambda: [p[3], p[4], 0.0, 0.0],
        "OPENCV": lambda: list(p[4:8]),
        "FULL_OPENCV": lambda: list(p[4:12]),
    }.get(model)
    if coeffs is None:
        return K, None
    dist = np.asarray(coeffs(), np.float64)
    return K, (Distortion(K, dist) if np.any(dist != 0) else None)


def read_colmap_specs(
    root: Path, views: int, problems: Problems
) -> tuple[list[ViewSpec], list[ViewSpec], str]:
    """(train specs, test specs, split source) of a COLMAP scene folder."""
    loaded = _read_model(root, problems)
    if loaded is None:
        return [], [], ""
    model, recon = loaded
    specs = _view_specs(root, model, recon, problems)
    train_idx, test_idx, source = _split(root, model, specs, views, problems)
    if train_idx is None:
        return [], [], source
    train = [specs[i] for i in train_idx if specs[i] is not None]
    test = [specs[i] for i in (test_idx or []) if specs[i] is not None]
    return train, test, source


def _read_model(root: Path, problems: Problems):
    """(model folder, pycolmap.Reconstruction) of the scene, or None with the problem recorded."""
    import pycolmap

    model = find_model_dir(root)
    if model is None:
        where = root / "sparse" / "0"
        problems.add("missing COLMAP model: expected sparse/0/cameras.bin or cameras.txt", where)
        return None
    if (model / "cameras.txt").is_file() and not (model / "cameras.bin").is_file():
        if not _prescan_text(model, problems):
            return None
    try:
        return model, pycolmap.Reconstruction(str(model))
    except Exception as exc:  # pycolmap raises ValueError/IndexError/RuntimeError with C++ check text
        msg = " ".join(str(exc).split())
        problems.add(f"cannot read the COLMAP model ({msg})", model)
        return None


def _view_specs(root: Path, model: Path, recon, problems: Problems) -> list[ViewSpec | None]:
    """One spec per registered image in name order (None where its camera, pose or file is bad, with the
    problem recorded); duplicate names are problems too."""
    cameras = {}
    for cam_id, cam in sorted(recon.cameras.items()):
        parts = _camera_parts(cam, problems, model)
        if parts is not None:
            cameras[cam_id] = (cam, parts)

    registered = sorted(
        (im for im in recon.images.values() if im.has_pose), key=lambda im: (im.name, im.image_id)
    )
    seen: dict[str, int] = {}
    for im in registered:
        if im.name in seen:
            ids = f"image ids {seen[im.name]} and {im.image_id}"
            problems.add(f"duplicate image name {im.name!r} ({ids})", model)
        seen.setdefault(im.name, im.image_id)

    specs: list[ViewSpec | None] = []
    for im in registered:
        label = f"image {im.name}"
        if im.camera_id not in cameras:
            specs.append(None)
            continue
        cam, (K, dist) = cameras[im.camera_id]
        w2c = np.eye(4)
        w2c[:3] = np.asarray(im.cam_from_world().matrix(), np.float64)
        if not check_rigid(w2c, problems, model, label):
            specs.append(None)
            continue
        path = root / "images" / im.name
        if not path.is_file():
            problems.add(f"image not found (registered in the COLMAP model as {im.name!r})", path)
            specs.append(None)
            continue
        stem = Path(im.name).with_suffix("")
        mask = find_mask_file([root / "masks" / im.name, root / "masks" / stem])
        camera = Camera(view_name(path, root / "images"), int(cam.width), int(cam.height), K, w2c)
        specs.append(ViewSpec(camera, path, mask, dist, where=model))
    return specs


def _split(root: Path, model: Path, specs: list, views: int, problems: Problems):
    """(train indices or None, test indices or None, source) of the registered images: a split file for
    ``views``, a farthest-point choice of ``views``, the one split file, or all images; sparse_test.txt
    names the test images, else the images not trained on are."""
    count = len(specs)
    files = split_files(root)
    test_file = root / "sparse_test.txt"
    test_idx = _read_split_file(test_file, count, problems) if test_file.is_file() else None
    pool = [i for i in range(count) if test_idx is None or i not in test_idx]
    if views > 0 and views in files:
        train_idx = _read_split_file(files[views], count, problems)
        source = files[views].name
        if train_idx is not None and len(train_idx) != views:
            problems.add(f"lists {len(train_idx)} indices, expected {views}", files[views])
    elif views > 0:
        if views > len(pool):
            problems.add(f"views={views} requested but only {len(pool)} training images are available", model)
            train_idx = None
        else:
            pool_cams = [specs[i].camera if specs[i] is not None else None for i in pool]
            valid = [j for j, c in enumerate(pool_cams) if c is not None]
            chosen = farthest_point_choice([pool_cams[j] for j in valid], views)
            train_idx = sorted(pool[valid[j]] for j in chosen)
        source = f"farthest-point choice of {views} of {len(pool)} images"
    elif len(files) == 1:
        n, f = next(iter(files.items()))
        train_idx = _read_split_file(f, count, problems)
        source = f.name
    else:
        train_idx = pool
        source = "all non-test images" if test_idx is not None else "all images"
    if test_idx is not None:
        source += " + sparse_test.txt"
        if train_idx is not None:
            both = sorted(set(train_idx) & set(test_idx))
            if both:
                problems.add(
                    f"indices {both} are in both the training split ({source.split(' + ')[0]}) and "
                    "the test split",
                    test_file,
                )
    elif train_idx is not None and len(train_idx) < count:
        test_idx = [i for i in range(count) if i not in train_idx]
        source += " (test: the other images)"
    return train_idx, test_idx, source
