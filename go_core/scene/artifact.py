"""The ``scene`` step's artifact: how every downstream step reads the scene.

Use ``load_scene_artifact(inputs["scene_step_dir"])`` — NOT the raw scene folder — so every step sees the
same chosen views, the same downscaling and the same camera convention::

    from go_core.scene.artifact import load_scene_artifact
    scene = load_scene_artifact(inputs["scene"])   # a go_core.scene.types.Scene
    for view in scene.train: view.camera, view.image, view.mask

Layout of an artifact folder (both files written atomically, byte-for-byte deterministic):

``scene.json``  (JSON Schema: ``data_schema/scene_manifest.schema.json``)
    ``{"schema": "go-pipeline/scene-manifest", "schema_version": 1, "format": "nerf"|"colmap",
    "split_source": "...", "views_requested": N, "max_size": M,
    "train": [camera, ...], "test": [camera, ...]}`` where each camera is
    ``{"name", "width", "height", "K": 3x3, "world_to_cam": 4x4, "source": "train/r_0.png",
    "mask_source": "masks/x.png" | null, "has_mask": bool, "array": "train_000"}``.
    Cameras follow ``go_core.camera`` (OpenCV: x right, y down, z forward; K with pixel centres at +0.5).
``views.npz``
    ``<array>_image`` [H, W, 3] and, when ``has_mask``, ``<array>_mask`` [H, W] for every camera, where
    ``<array>`` is ``train_000``, ``train_001``, ..., ``test_000``, ... Each array is stored as ``uint8``
    (value/255) when that is exact (8-bit sources, no resampling), else as ``float16`` (16-bit/EXR sources
    or downscaled images); loading always gives float32 like ``go_core.scene.types.View``.

``Scene.root`` of a loaded artifact is the artifact folder (the raw scene folder is not part of the artifact,
so moving a scene does not change downstream cache keys); ``View.source`` is the source image path relative
to the original scene folder.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from go_core import artifact_files as artifacts
from go_core.camera import Camera
from go_core.errors import SceneError
from go_core.io.atomic import atomic_write_json
from go_core.io.npz import write_npz_deterministic  # noqa: F401  (re-exported)
from go_core.scene.types import Scene, View

MANIFEST = artifacts.SCENE_INFO.file
ARRAYS = artifacts.SCENE_VIEWS.file
SCHEMA_ID = "go-pipeline/scene-manifest"
SCHEMA_VERSION = 1


def _array_name(split: str, index: int) -> str:
    return f"{split}_{index:03d}"


def _compact(a: np.ndarray) -> np.ndarray:
    """uint8 when the float values are exact multiples of 1/255 in [0, 1], else float16."""
    a = np.asarray(a, np.float32)
    if a.size and np.isfinite(a).all() and a.min() >= 0.0 and a.max() <= 1.0:
        q = np.round(a * np.float32(255.0))
        if np.array_equal((q / np.float32(255.0)).astype(np.float32), a):
            return q.astype(np.uint8)
    return a.astype(np.float16)


def _expand(a: np.ndarray) -> np.ndarray:
    if a.dtype == np.uint8:
        return a.astype(np.float32) / np.float32(255.0)
    return a.astype(np.float32)


def _camera_json(view: View, split: str, index: int, root: Path | None) -> dict[str, Any]:
    cam = view.camera
    return {
        "name": cam.name,
        "width": int(cam.width),
        "height": int(cam.height),
        "K": [[float(x) for x in row] for row in cam.K],
        "world_to_cam": [[float(x) for x in row] for row in cam.world_to_cam],
        "source": _rel(view.source, root),
        "mask_source": _rel(view.mask_source, root),
        "has_mask": view.mask is not None,
        "array": _array_name(split, index),
    }


def _rel(path: Path | str | None, root: Path | None) -> str | None:
    if path is None:
        return None
    p = Path(path)
    if root is not None and p.is_absolute():
        try:
            return p.relative_to(root).as_posix()
        except ValueError:
            pass
    return p.as_posix()


@dataclass(frozen=True)
class Ingest:
    """How the ``scene`` step made the artifact (recorded in ``scene.json``)."""

    split_source: str = ""  # where the train/test split came from ("": the scene's own)
    views_requested: int = 0  # --views N (0: the scene's own split)
    max_size: int = 0  # the downscale limit applied (0: none)
    given_poses: dict[str, np.ndarray] | None = None  # the folder's own poses of views whose were estimated
    poses: str = "given"  # or how the training poses were estimated


def scene_manifest(scene: Scene, ingest: Ingest = Ingest()) -> dict:
    """The ``scene.json`` content for ``scene`` (see the module docstring); the folder's own poses of
    views whose cameras were estimated are kept beside them (``given_world_to_cam``, for the CF eval)."""
    root = Path(scene.root) if scene.root is not None else None
    train = [_camera_json(v, "train", i, root) for i, v in enumerate(scene.train)]
    given = ingest.given_poses or {}
    for cam in train:
        if cam["name"] in given:
            cam["given_world_to_cam"] = [[float(x) for x in row] for row in given[cam["name"]]]
    manifest = {
        "schema": SCHEMA_ID,
        "schema_version": SCHEMA_VERSION,
        "format": scene.format,
        "split_source": ingest.split_source or scene.split_source,
        "views_requested": int(ingest.views_requested),
        "max_size": int(ingest.max_size),
        "train": train,
        "test": [_camera_json(v, "test", i, root) for i, v in enumerate(scene.test)],
    }
    if ingest.poses != "given":
        manifest["poses"] = ingest.poses
    return manifest


def save_scene_artifact(scene: Scene, out_dir: str | Path, ingest: Ingest = Ingest()) -> dict:
    """Write ``scene.json`` and ``views.npz`` into ``out_dir``; returns the manifest dict."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    manifest = scene_manifest(scene, ingest)
    arrays: dict[str, np.ndarray] = {}
    for split, views in (("train", scene.train), ("test", scene.test)):
        for i, v in enumerate(views):
            key = _array_name(split, i)
            arrays[f"{key}_image"] = _compact(v.image)
            if v.mask is not None:
                arrays[f"{key}_mask"] = _compact(v.mask)
    write_npz_deterministic(out_dir / ARRAYS, arrays)
    atomic_write_json(out_dir / MANIFEST, manifest)
    return manifest


def read_scene_manifest(artifact_dir: str | Path) -> dict:
    """``scene.json`` of a scene artifact as a dict (cameras only, no pixels)."""
    path = Path(artifact_dir) / MANIFEST
    if not path.is_file():
        raise SceneError("scene artifact manifest is missing (run the `scene` step first)", path=path)
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise SceneError(f"unreadable scene manifest ({exc})", path=path) from exc
    if manifest.get("schema") != SCHEMA_ID:
        raise SceneError(f"not a scene manifest (schema={manifest.get('schema')!r})", path=path)
    return manifest


def camera_from_json(d: dict) -> Camera:
    return Camera(
        str(d["name"]),
        int(d["width"]),
        int(d["height"]),
        np.asarray(d["K"], np.float64),
        np.asarray(d["world_to_cam"], np.float64),
    )


def load_given_train_cameras(artifact_dir: str | Path) -> list[Camera]:
    """The training cameras as the scene folder gave them (differs from ``load_scene_cameras`` only for
    views whose poses were estimated)."""
    m = read_scene_manifest(artifact_dir)
    cams = []
    for c in m["train"]:
        given = {**c, "world_to_cam": c["given_world_to_cam"]} if "given_world_to_cam" in c else c
        cams.append(camera_from_json(given))
    return cams


def load_scene_cameras(artifact_dir: str | Path) -> tuple[list[Camera], list[Camera]]:
    """(train cameras, test cameras) of a scene artifact without reading any pixels."""
    m = read_scene_manifest(artifact_dir)
    return [camera_from_json(c) for c in m["train"]], [camera_from_json(c) for c in m["test"]]


def load_scene_artifact(artifact_dir: str | Path) -> Scene:
    """Read a ``scene`` step artifact back into a ``Scene`` (float32 images/masks, OpenCV cameras)."""
    artifact_dir = Path(artifact_dir)
    manifest = read_scene_manifest(artifact_dir)
    npz_path = artifact_dir / ARRAYS
    if not npz_path.is_file():
        raise SceneError("scene artifact images are missing", path=npz_path)
    splits: dict[str, list[View]] = {"train": [], "test": []}
    with np.load(npz_path, allow_pickle=False) as data:
        for split in ("train", "test"):
            for c in manifest[split]:
                key = c["array"]
                if f"{key}_image" not in data.files:
                    raise SceneError(f"array {key}_image is missing", path=npz_path)
                image = _expand(data[f"{key}_image"])
                mask = _expand(data[f"{key}_mask"]) if c.get("has_mask") else None
                source = Path(c["source"]) if c.get("source") else None
                mask_source = Path(c["mask_source"]) if c.get("mask_source") else None
                splits[split].append(View(camera_from_json(c), image, mask, source, mask_source))
    split_source = manifest.get("split_source", "")
    return Scene(artifact_dir, manifest["format"], splits["train"], splits["test"], split_source)
