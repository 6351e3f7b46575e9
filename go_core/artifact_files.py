"""The file names of every artifact, in one place (a leaf module: go_core's format modules import it, and
go_core.artifacts re-exports it with the typed readers and writers)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


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
SCENE_PHOTOS = Artifact("photos.json", "a photo folder's masks, SfM attempts, registration and view choice")
# Masks and depth priors (go_core.scene.masking, go_core.coarse.depth_prior)
MASKS = Artifact("masks.npz", "training masks, float32 [H,W] each (train_000, ...)")
MASK_INFO = Artifact("mask.json", "the mask method and per-view statistics")
DEPTH = Artifact("depth.npz", "monocular disparity priors (empty when the depth step skipped)")
DEPTH_INFO = Artifact("depth.json", "the depth model used, or why the depth step skipped")
# Gaussian sets (go_core.gaussians)
GAUSSIANS = Artifact("gaussians.npz", "a set of 3D Gaussians")
HULL_INFO = Artifact("hull.json", "the initialisation: point count, bounding box, volume")
COARSE_INFO = Artifact("coarse.json", "coarse training: counts, settings, loss log")
CAMERAS = Artifact(
    "cameras.json",
    "training cameras: hull's when aligned (hull.align_poses), coarse's fitted ones (coarse.refine_poses)",
)
CURVES = Artifact("curves.csv", "training curves: loss, train PSNR, Gaussians per logged step")
# The repair chain
WEIGHTS_INFO = Artifact("weights.json", "the repair model's weights, or why they are missing")
LOO_INFO = Artifact("loo.json", "leave-one-out runs, 3D-noise statistics, pair index")
LOO_PAIRS = Artifact("loo_pairs.npz", "leave-one-out degraded / clean / mask images, uint8")
NOISE_PAIRS_INFO = Artifact("noise_pairs.json", "noise-pair settings and statistics")
NOISE_PAIRS_PREVIEW = Artifact("preview.png", "photo | render | noisy render for each training view")
TUNE_INFO = Artifact("tune.json", "the repair model's per-scene tuning: what was tuned, how, and its losses")
LORA_WEIGHTS = Artifact("lora.safetensors", "the tuned LoRA tensors")
COMPACT_WEIGHTS = Artifact("compact.safetensors", "the compact restorer fine-tuned on the scene")
REPAIR_INFO = Artifact("repair.json", "repair summary; status ok means gaussians.npz is the repaired set")
REPAIR_PREVIEW = Artifact("repair_preview.png", "render | repaired image of the last refresh's views")
# Results
POINT_CLOUD = Artifact("point_cloud.ply", "the final Gaussians in the 3DGS PLY layout")
TURNTABLE = Artifact("turntable.gif", "frames on the ellipse of the training cameras")
CONTACT_SHEET = Artifact("contact_sheet.png", "a few turntable frames side by side")
CAMERA_PATH_VIDEO = Artifact("camera_path.mp4", "a video along a closed path through the training cameras")
MESH_PLY = Artifact("model_mesh.ply", "the final model's surface: binary PLY, world frame, vertex colours")
MESH_GLB = Artifact("model.glb", "the same mesh as glTF 2.0 binary (+Y up, centred)")
HULL_MESH = Artifact("hull_mesh.ply", "the visual hull's surface (the geometry baseline)")
MESH_INFO = Artifact("mesh.json", "mesh extraction: settings, counts, seconds")
GT_MESH = Artifact("mesh_world.npz", "ground-truth mesh of the scene folder, when it has one (evaluation)")
METRICS = Artifact("metrics.json", "test-view PSNR / SSIM / LPIPS (metrics schema)")
TEST_GRID = Artifact("test_grid.png", "ground truth, render and error map of test views")
GEOMETRY_PICTURE = Artifact(
    "geometry.png", "ground-truth mesh | final mesh | visual hull mesh, one test view"
)

STATUS_OK = "ok"
STATUS_SKIPPED = "skipped"

__all__ = [
    "Artifact",
    "SCENE_INFO",
    "SCENE_VIEWS",
    "SCENE_PHOTOS",
    "MASKS",
    "MASK_INFO",
    "DEPTH",
    "DEPTH_INFO",
    "GAUSSIANS",
    "HULL_INFO",
    "COARSE_INFO",
    "CAMERAS",
    "CURVES",
    "WEIGHTS_INFO",
    "LOO_INFO",
    "LOO_PAIRS",
    "NOISE_PAIRS_INFO",
    "NOISE_PAIRS_PREVIEW",
    "TUNE_INFO",
    "LORA_WEIGHTS",
    "COMPACT_WEIGHTS",
    "REPAIR_INFO",
    "REPAIR_PREVIEW",
    "POINT_CLOUD",
    "TURNTABLE",
    "CONTACT_SHEET",
    "CAMERA_PATH_VIDEO",
    "MESH_PLY",
    "MESH_GLB",
    "HULL_MESH",
    "MESH_INFO",
    "GT_MESH",
    "METRICS",
    "TEST_GRID",
    "GEOMETRY_PICTURE",
    "STATUS_OK",
    "STATUS_SKIPPED",
]
