"""The artifact catalog: every file a pipeline step writes, by name, with typed readers and writers.

File names live here and only here (the step modules never spell one; the runner's declared outputs come
from go_pipeline.catalog, which lists these per step). The folder formats of go_core (the ingested scene,
masks, depth priors) take their names from here too. Torch-free to import: readers import what they need.

    from go_core import artifacts as art
    g = art.read_gaussians(inputs["hull"])         # Gaussians from the hull step's folder
    art.write_gaussians(ctx.out_dir, g)
    info = art.read_json(inputs["weights"], art.WEIGHTS_INFO)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
    import numpy as np

    from go_core.camera import Camera
    from go_core.gaussians import Gaussians
    from go_core.scene.types import Scene


@dataclass(frozen=True)
class Artifact:
    """One file of a step's artifact folder."""

    file: str
    description: str

    def path(self, folder: str | Path) -> Path:
        return Path(folder) / self.file


# The ingested scene (go_core.scene.artifact)
SCENE_INFO = Artifact("scene.json", "the ingested scene: cameras, splits, image names")
SCENE_VIEWS = Artifact("views.npz", "the ingested scene's images and masks, uint8")
# Masks and depth priors (go_core.masking, go_core.depth_prior)
MASKS = Artifact("masks.npz", "training masks, float32 [H,W] each (train_000, ...)")
MASK_INFO = Artifact("mask.json", "the mask method and per-view statistics")
DEPTH = Artifact("depth.npz", "monocular disparity priors (empty when the depth step skipped)")
DEPTH_INFO = Artifact("depth.json", "the depth model used, or why the depth step skipped")
# Gaussian sets (go_core.gaussians)
GAUSSIANS = Artifact("gaussians.npz", "a set of 3D Gaussians")
HULL_INFO = Artifact("hull.json", "the initialisation: point count, bounding box, volume")
COARSE_INFO = Artifact("coarse.json", "coarse training: counts, settings, loss log")
CURVES = Artifact("curves.csv", "training curves: loss, train PSNR, Gaussians per logged step")
# The repair chain
WEIGHTS_INFO = Artifact("weights.json", "the repair model's weights, or why they are missing")
LOO_INFO = Artifact("loo.json", "leave-one-out runs, 3D-noise statistics, pair index")
LOO_PAIRS = Artifact("loo_pairs.npz", "leave-one-out degraded / clean / mask images, uint8")
NOISE_PAIRS_INFO = Artifact("noise_pairs.json", "noise-pair settings and statistics")
NOISE_PAIRS_PREVIEW = Artifact("preview.png", "photo | render | noisy render for each training view")
LORA_INFO = Artifact("lora.json", "LoRA tuning summary")
LORA_WEIGHTS = Artifact("lora.safetensors", "the tuned LoRA tensors")
COMPACT_WEIGHTS = Artifact("compact.safetensors", "the compact restorer fine-tuned on the scene")
REPAIR_INFO = Artifact("repair.json", "repair summary; status ok means gaussians.npz is the repaired set")
REPAIR_PREVIEW = Artifact("repair_preview.png", "render | repaired image of the last refresh's views")
# Results
POINT_CLOUD = Artifact("point_cloud.ply", "the final Gaussians in the 3DGS PLY layout")
TURNTABLE = Artifact("turntable.gif", "frames on the ellipse of the training cameras")
CONTACT_SHEET = Artifact("contact_sheet.png", "a few turntable frames side by side")
CAMERA_PATH_VIDEO = Artifact("camera_path.mp4", "a video along a closed path through the training cameras")
METRICS = Artifact("metrics.json", "test-view PSNR / SSIM / LPIPS (metrics schema)")
TEST_GRID = Artifact("test_grid.png", "ground truth, render and error map of test views")

STATUS_OK = "ok"
STATUS_SKIPPED = "skipped"


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


def write_scene(out_dir: str | Path, scene: Scene, views_requested: int = 0, max_size: int = 0) -> dict:
    """``scene.json`` + ``views.npz`` for ``scene``; returns the manifest written."""
    from go_core.scene.artifact import save_scene_artifact

    return save_scene_artifact(scene, out_dir, views_requested=views_requested, max_size=max_size)


def read_masks(folder: str | Path, count: int | None = None) -> list[np.ndarray]:
    """The ``mask`` step's training masks in view order (``count``: the number expected, else an error)."""
    from go_core.masking import load_masks

    return load_masks(folder, count)


def write_masks(out_dir: str | Path, masks: list[np.ndarray]) -> Path:
    from go_core.masking import save_masks

    return save_masks(out_dir, masks)


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
