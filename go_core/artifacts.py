"""The artifact catalog: every file a pipeline step writes, by name, with typed readers and writers.

File names are defined once, in go_core.artifact_files (a leaf module, so the folder formats of go_core,
the ingested scene, masks and depth priors, take their names from it without an import cycle), and
re-exported here; the step modules never spell one, and the runner's declared outputs come from
go_pipeline.steps.registry, which lists these per step. Torch-free to import: readers import what they need.

    from go_core import artifacts as art
    g = art.read_gaussians(inputs["hull"])         # Gaussians from the hull step's folder
    art.write_gaussians(ctx.out_dir, g)
    info = art.read_json(inputs["weights"], art.WEIGHTS_INFO)
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
    import numpy as np

    from go_core.camera import Camera
    from go_core.gaussians import Gaussians
    from go_core.scene.artifact import Ingest
    from go_core.scene.types import Scene

from go_core.artifact_files import *  # noqa: F403  (the names: one definition, re-exported)
from go_core.artifact_files import CAMERAS, GAUSSIANS, REPAIR_INFO, SCENE_INFO, STATUS_OK, Artifact


# Readers and writers --------------------------------------------------------------------------------------
def read_json(folder: str | Path, artifact: Artifact) -> dict[str, Any]:
    import json

    return json.loads(artifact.path(folder).read_text(encoding="utf-8"))


def write_json(out_dir: str | Path, artifact: Artifact, data: dict[str, Any]) -> Path:
    from go_core.io.atomic import atomic_write_json

    return atomic_write_json(artifact.path(out_dir), data)


def read_scene(folder: str | Path) -> Scene:
    """The ingested scene of the ``scene`` step's folder (float32 images and masks, OpenCV cameras)."""
    from go_core.scene.artifact import load_scene_artifact

    return load_scene_artifact(folder)


def read_scene_cameras(folder: str | Path) -> tuple[list[Camera], list[Camera]]:
    """(train, test) cameras of the ``scene`` step's folder, without reading any pixels."""
    from go_core.scene.artifact import load_scene_cameras

    return load_scene_cameras(folder)


def write_scene(out_dir: str | Path, scene: Scene, ingest: Ingest | None = None) -> dict:
    """``scene.json`` + ``views.npz`` for ``scene`` (``ingest``: how it was made); returns the manifest."""
    from go_core.scene.artifact import Ingest, save_scene_artifact

    return save_scene_artifact(scene, out_dir, ingest or Ingest())


def read_given_train_cameras(folder: str | Path) -> list[Camera]:
    """The training cameras as the scene folder gave them (for aligning its test cameras)."""
    from go_core.scene.artifact import load_given_train_cameras

    return load_given_train_cameras(folder)


def poses_estimated(folder: str | Path) -> bool:
    """Whether the ``scene`` step estimated the training poses (scene.poses=estimate)."""
    return read_json(folder, SCENE_INFO).get("poses", "given") != "given"


def read_masks(folder: str | Path, count: int | None = None) -> list[np.ndarray]:
    """The ``mask`` step's training masks in view order (``count``: the number expected, else an error)."""
    from go_core.scene.masking import load_masks

    return load_masks(folder, count)


def write_masks(out_dir: str | Path, masks: list[np.ndarray]) -> Path:
    from go_core.scene.masking import save_masks

    return save_masks(out_dir, masks)


def write_cameras(
    out_dir: str | Path,
    cameras: list[Camera],
    corrections: list[list[float]] | None = None,
    aligned: bool = False,
) -> Path:
    """``cameras.json``: the training cameras a model was fitted with; ``corrections`` (per view
    [ωx, ωy, ωz, τx, τy, τz], go_core.poses.refine) when refined, with each view's rotation change;
    ``aligned`` when they were turned by the hull's silhouette alignment. ``refined`` is true when either
    moved them: the model then lives in their frame, not the scene folder's (eval's CF protocol)."""
    import math

    rows = []
    for i, c in enumerate(cameras):
        row = {
            "name": c.name,
            "width": int(c.width),
            "height": int(c.height),
            "K": [[float(x) for x in r] for r in c.K],
            "world_to_cam": [[float(x) for x in r] for r in c.world_to_cam],
        }
        if corrections is not None:
            row["correction"] = [float(x) for x in corrections[i]]
            row["rotation_change_deg"] = math.degrees(math.sqrt(sum(x * x for x in corrections[i][:3])))
        rows.append(row)
    refined = corrections is not None or aligned
    return write_json(out_dir, CAMERAS, {"refined": refined, "aligned": aligned, "cameras": rows})


def cameras_aligned(folder: str | Path) -> bool:
    """Whether ``folder``'s ``cameras.json`` holds cameras turned by the hull's silhouette alignment."""
    return CAMERAS.path(folder).is_file() and bool(read_json(folder, CAMERAS).get("aligned", False))


def read_fitted_cameras(folder: str | Path, given: list[Camera]) -> list[Camera]:
    """The training cameras ``folder``'s ``cameras.json`` holds (hull: aligned; coarse: the ones the model
    was fitted with), else ``given`` (a step that moved nothing, or a custom step, writes none); a
    SceneError when they are not the same views in the same order."""
    if not CAMERAS.path(folder).is_file():
        return list(given)
    fitted = read_cameras(folder)
    if [c.name for c in fitted] != [c.name for c in given]:
        from go_core.errors import SceneError

        raise SceneError("the cameras are not the scene's training views", CAMERAS.path(folder))
    return fitted


def read_cameras(folder: str | Path) -> list[Camera]:
    """The cameras of ``cameras.json``, in training-view order."""
    from go_core.scene.artifact import camera_from_json

    return [camera_from_json(c) for c in read_json(folder, CAMERAS)["cameras"]]


def read_gaussians(folder: str | Path) -> Gaussians:
    from go_core.gaussians import Gaussians

    return Gaussians.load(GAUSSIANS.path(folder))


def write_gaussians(out_dir: str | Path, gaussians: Gaussians) -> Path:
    path = GAUSSIANS.path(out_dir)
    gaussians.save(path)
    return path


def status(folder: str | Path, artifact: Artifact) -> str:
    """The ``status`` of a step's summary JSON (``ok``, ``skipped``, ...)."""
    return str(read_json(folder, artifact).get("status"))


class FinalModel(NamedTuple):
    folder: Path  # holds gaussians.npz
    source: str  # "repair" | "coarse"
    repair_info: dict[str, Any] | None  # the repair step's summary (None: no repair step or no summary)


def final_model(coarse: str | Path, repair: str | Path | None) -> FinalModel:
    """The Gaussians downstream steps use: the repaired set when the repair step produced one, else the
    coarse set (the repair summary is read once, here, and handed on)."""
    has_info = repair is not None and REPAIR_INFO.path(repair).is_file()
    info = read_json(repair, REPAIR_INFO) if has_info else None
    if info is not None and info.get("status") == STATUS_OK:
        return FinalModel(Path(repair), "repair", info)
    return FinalModel(Path(coarse), "coarse", info)
