"""``load_scene``: detect a scene folder's format, read it into a ``Scene``, choose views, downscale.

Format detection: ``transforms_train.json``/``transforms_test.json`` → NeRF-synthetic (``nerf.py``);
else a ``sparse/`` folder → COLMAP (``colmap.py``). ``views=N`` chooses N training views when the scene has
more (COLMAP: ``sparse_N.txt`` when present; otherwise, and for NeRF scenes, a deterministic farthest-point
choice on the viewing directions starting from the first view in file/name order; the test split is kept).
``max_size`` downscales with an area filter so the longest side is at most ``max_size``.
"""

from __future__ import annotations

from pathlib import Path

from go_core.errors import SceneError
from go_core.scene.colmap import is_colmap_scene, read_colmap_specs
from go_core.scene.common import (
    Problems,
    ViewSpec,
    check_masks,
    farthest_point_choice,
    load_views,
    resize_view,
)
from go_core.scene.nerf import TEST_FILE, TRAIN_FILE, is_nerf_scene, read_nerf_specs
from go_core.scene.types import Scene


def detect_format(root: Path) -> str | None:
    if is_nerf_scene(root):
        return "nerf"
    if is_colmap_scene(root):
        return "colmap"
    return None


def _check_duplicates(train: list[ViewSpec], test: list[ViewSpec], problems: Problems) -> None:
    seen: dict[Path, str] = {}
    names: dict[str, str] = {}
    for split, specs in (("train", train), ("test", test)):
        for s in specs:
            key = s.image_path.resolve()
            if key in seen:
                problems.add(
                    f"duplicate image {s.image_path.name!r}: used by two views ({seen[key]} and {split})",
                    s.where or s.image_path,
                )
                continue
            if s.camera.name in names:
                problems.add(
                    f"duplicate image name {s.camera.name!r} ({names[s.camera.name]} and {split})",
                    s.where or s.image_path,
                )
                continue
            seen[key] = split
            names[s.camera.name] = split


def _not_a_scene_message(root: Path) -> str:
    """What is missing, and for a folder of plain photos the command that estimates their poses."""
    from go_core.io.images import IMAGE_EXTENSIONS

    msg = f"not a scene folder: no {TRAIN_FILE} (NeRF-synthetic) and no sparse/0 (COLMAP)"
    for folder in (root, root / "images"):
        photos = [f for f in folder.iterdir() if f.suffix in IMAGE_EXTENSIONS] if folder.is_dir() else []
        if photos:
            out = folder / TRAIN_FILE if folder == root else root / TRAIN_FILE
            msg += (
                f". It holds {len(photos)} photos without poses: `go-pipeline run {root}` masks and poses "
                "them all (docs/photos.md), or estimate them with "
                f"`go-pipeline poses {folder} --estimate {out}`"
            )
            break
    return msg


def scene_input_files(path: str | Path) -> list[Path]:
    """Every file the reader opens for the scene at ``path`` (format files, images, masks), as the reader
    names them (a ``file_path`` may be absolute or lead out of the folder with ``..``). Cheap: the format
    files are parsed, no pixel is read. Problems are left to the reader; what can be named is listed."""
    from go_core.scene.nerf import TEST_FILE

    root = Path(path)
    problems = Problems(strict=False)
    fmt = detect_format(root)
    if fmt == "nerf":
        train, test = read_nerf_specs(root, problems)
        files = [root / f for f in (TRAIN_FILE, TEST_FILE) if (root / f).is_file()]
    elif fmt == "colmap":
        train, test, _ = read_colmap_specs(root, 0, problems)
        files = []
    else:
        return []
    for spec in train + test:
        files.append(spec.image_path)
        if spec.mask_path is not None:
            files.append(spec.mask_path)
    return files


def read_scene_folder(path: str | Path, views: int, max_size: int, problems: Problems) -> Scene | None:
    """Read a scene, reporting every problem to ``problems``; None when nothing usable was read."""
    root = Path(path)
    if not root.is_dir():
        problems.add("scene folder not found" if not root.exists() else "scene path is not a folder", root)
        return None
    if views < 0 or views == 1:
        problems.add(f"views={views}: choose 0 (the scene's own split) or at least 2 training views", root)
        return None
    fmt = detect_format(root)
    if fmt is None:
        problems.add(_not_a_scene_message(root), root)
        return None
    if fmt == "nerf":
        train_specs, test_specs = read_nerf_specs(root, problems)
        source = TRAIN_FILE
        if views > 0:
            if views > len(train_specs):
                problems.add(
                    f"views={views} requested but the scene has only {len(train_specs)} training views",
                    root / TRAIN_FILE,
                )
            elif views < len(train_specs):
                chosen = farthest_point_choice([s.camera for s in train_specs], views)
                source = f"farthest-point choice of {views} of {len(train_specs)} in {TRAIN_FILE}"
                train_specs = [train_specs[i] for i in chosen]
        if (root / TEST_FILE).is_file():
            source += f" + {TEST_FILE}"
    else:
        train_specs, test_specs, source = read_colmap_specs(root, views, problems)
    _check_duplicates(train_specs, test_specs, problems)
    train = load_views(train_specs, problems)
    test = load_views(test_specs, problems)
    check_masks(train + test, problems)
    if len(train) < 2 and not len(problems):  # else it is a consequence of the problems already listed
        where = root / TRAIN_FILE if fmt == "nerf" else root
        problems.add(f"fewer than 2 training views ({len(train)} usable); at least 2 are needed", where)
    largest = max((max(v.camera.width, v.camera.height) for v in train + test), default=0)
    if max_size < 0:
        problems.add(f"max_size={max_size} must be 0 (keep) or positive", root)
    elif max_size > 0:
        train = [resize_view(v, max_size) for v in train]
        test = [resize_view(v, max_size) for v in test]
    return Scene(root, fmt, train, test, source, original_max_side=largest)


def load_scene(path: str | Path, views: int = 0, max_size: int = 0) -> Scene:
    """Read the scene folder ``path`` into a ``Scene`` (see the module docstring).

    Raises ``SceneError`` (one line naming the file and the problem) at the first problem found; use
    ``go_core.scene.validate.validate_scene`` to list every problem at once."""
    problems = Problems(strict=True)
    scene = read_scene_folder(path, views, max_size, problems)
    if scene is None:  # pragma: no cover - strict mode raises before this
        raise SceneError("could not read the scene", path=path)
    return scene
