"""Which artifacts each step writes: the runner's declared outputs (checked after the step returns).

The files themselves, their names and readers/writers, are go_core.artifacts; this maps the packaged step
modules to them, so pipeline.yaml does not list outputs for these steps (a step of your own still declares
``outputs:`` in pipeline.yaml).
"""

from __future__ import annotations

from go_core import artifacts as art

STEP_OUTPUTS: dict[str, tuple[art.Artifact, ...]] = {
    "go_pipeline.steps.scene": (art.SCENE_INFO, art.SCENE_VIEWS),
    "go_pipeline.steps.mask": (art.MASKS, art.MASK_INFO),
    "go_pipeline.steps.depth": (art.DEPTH_INFO, art.DEPTH),
    "go_pipeline.steps.hull": (art.GAUSSIANS, art.HULL_INFO),
    "go_pipeline.steps.coarse": (art.GAUSSIANS, art.COARSE_INFO, art.CURVES, art.CAMERAS),
    "go_pipeline.steps.weights": (art.WEIGHTS_INFO,),
    "go_pipeline.steps.loo": (art.LOO_INFO, art.LOO_PAIRS),
    "go_pipeline.steps.noise_pairs": (art.NOISE_PAIRS_INFO,),
    "go_pipeline.steps.lora": (art.LORA_INFO,),
    "go_pipeline.steps.repair": (art.REPAIR_INFO,),
    "go_pipeline.steps.export": (art.POINT_CLOUD,),
    "go_pipeline.steps.turntable": (art.TURNTABLE, art.CONTACT_SHEET, art.CAMERA_PATH_VIDEO),
    "go_pipeline.steps.eval": (art.METRICS, art.TEST_GRID),
}
# files a step writes only in some runs (it says which in its info file): shown by `dag`, never required
OPTIONAL_OUTPUTS: dict[str, tuple[art.Artifact, ...]] = {
    "go_pipeline.steps.hull": (art.CAMERAS,),  # hull.align_poses
    "go_pipeline.steps.noise_pairs": (art.NOISE_PAIRS_PREVIEW,),  # when it did not skip
    "go_pipeline.steps.lora": (art.LORA_WEIGHTS, art.COMPACT_WEIGHTS),  # sd15 / compact, when it tuned
    "go_pipeline.steps.repair": (art.GAUSSIANS, art.CURVES, art.REPAIR_PREVIEW),  # status ok
}


def declared_outputs(module: str) -> tuple[str, ...] | None:
    """File names a packaged step module must write, or None for a step the catalog does not know."""
    found = STEP_OUTPUTS.get(module)
    return None if found is None else tuple(a.file for a in found)


def optional_outputs(module: str) -> tuple[str, ...]:
    """File names a packaged step module writes only in some runs (empty for a step the catalog does not
    know)."""
    return tuple(a.file for a in OPTIONAL_OUTPUTS.get(module, ()))
