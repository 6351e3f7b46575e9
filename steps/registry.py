"""One declaration per packaged step: its params class, the files it writes, when the runner skips it
without starting a worker, and an optional version override.

The runner reads this at plan time (torch-free, no step module imported), so ``status`` and ``dag`` stay
cheap. No step module imports it: editing a declaration reruns nothing by itself, except a changed
``version``, which is part of the step's cache key. pipeline.yaml names the step's function and inputs and
the values a user changes; every default lives in the params class (``go-pipeline params`` lists them).
A step of your own (outside go_pipeline.steps) declares ``outputs:`` in pipeline.yaml and may declare
``VERSION`` / ``SKIP_IF_SKIPPED`` / ``SKIP_IF_EMPTY`` at the top of its module (read with ast).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

from go_pipeline.steps import params as p

from go_core import artifacts as art


@dataclass(frozen=True)
class StepDeclaration:
    params: type  # the step's params class (steps/params.py)
    outputs: tuple[art.Artifact, ...]  # written by every run (checked when the step returns)
    sometimes: tuple[art.Artifact, ...] = ()  # written only in some runs (its info file says which)
    skip_if_skipped: tuple[str, ...] = ()  # input names: the runner skips the step when one of them skipped
    skip_if_empty: dict[str, str] = field(default_factory=dict)  # {param: reason}: skipped while it is empty
    # {"step.param": {value: reason}}: skipped while another step's param has that value (in its cache key)
    skip_if_param: dict[str, dict[str, str]] = field(default_factory=dict)
    version: str | None = None  # forces a rerun without a code change (its code is in the key anyway)
    # input names the step reads only for skip_if_skipped: their status (ran, or skipped and why) is in the
    # key, not their content, so another repair model does not rerun the leave-one-out runs
    gate_inputs: tuple[str, ...] = ()


NO_REPAIR_REASON = "no repair (repair.mode no_repair): the coarse model is the result"
NO_TUNING_REASON = "no fine-tuning (tune.finetune false): the tuning pairs are not needed"
DEPTH_SKIP_REASON = "no depth model configured (depth.model_path is empty): the depth loss is off"

STEPS: dict[str, StepDeclaration] = {
    "go_pipeline.steps.scene": StepDeclaration(
        p.SceneParams, (art.SCENE_INFO, art.SCENE_VIEWS), sometimes=(art.SCENE_PHOTOS,)
    ),
    "go_pipeline.steps.mask": StepDeclaration(p.MaskParams, (art.MASKS, art.MASK_INFO)),
    "go_pipeline.steps.depth": StepDeclaration(
        p.DepthParams, (art.DEPTH_INFO, art.DEPTH), skip_if_empty={"model_path": DEPTH_SKIP_REASON}
    ),
    "go_pipeline.steps.hull": StepDeclaration(
        p.HullParams,
        (art.GAUSSIANS, art.HULL_INFO),
        sometimes=(art.CAMERAS,),  # hull.align_poses
    ),
    "go_pipeline.steps.coarse": StepDeclaration(
        p.CoarseParams, (art.GAUSSIANS, art.COARSE_INFO, art.CURVES, art.CAMERAS)
    ),
    # the "no repair" ablation: the runner skips the repair chain from its root (loo, noise_pairs, tune and
    # repair follow by skip_if_skipped), no worker started
    "go_pipeline.steps.weights": StepDeclaration(
        p.WeightsParams, (art.WEIGHTS_INFO,), skip_if_param={"repair.mode": {"no_repair": NO_REPAIR_REASON}}
    ),
    "go_pipeline.steps.loo": StepDeclaration(
        p.LooParams,
        (art.LOO_INFO, art.LOO_PAIRS),
        skip_if_skipped=("weights",),
        skip_if_param={"tune.finetune": {"False": NO_TUNING_REASON}},  # its pairs only feed the tuning
        gate_inputs=("weights",),
    ),
    "go_pipeline.steps.noise_pairs": StepDeclaration(
        p.NoisePairsParams,
        (art.NOISE_PAIRS_INFO,),
        (art.NOISE_PAIRS_PREVIEW,),
        skip_if_skipped=("weights", "loo"),
        gate_inputs=("weights",),
    ),
    "go_pipeline.steps.tune": StepDeclaration(
        p.TuneParams,
        (art.TUNE_INFO,),
        (art.LORA_WEIGHTS, art.COMPACT_WEIGHTS),  # sd15 / compact, when it tuned
        skip_if_skipped=("weights",),
    ),
    "go_pipeline.steps.repair": StepDeclaration(
        p.RepairParams,
        (art.REPAIR_INFO,),
        (art.GAUSSIANS, art.CURVES, art.REPAIR_PREVIEW),  # when it repaired (status ok)
        skip_if_skipped=("tune",),
    ),
    "go_pipeline.steps.export": StepDeclaration(p.ExportParams, (art.POINT_CLOUD,)),
    "go_pipeline.steps.mesh": StepDeclaration(
        p.MeshParams, (art.MESH_PLY, art.MESH_GLB, art.HULL_MESH, art.MESH_INFO)
    ),
    "go_pipeline.steps.turntable": StepDeclaration(
        p.TurntableParams, (art.TURNTABLE, art.CONTACT_SHEET, art.CAMERA_PATH_VIDEO)
    ),
    "go_pipeline.steps.eval": StepDeclaration(
        p.EvalParams,
        (art.METRICS, art.TEST_GRID),
        (art.GEOMETRY_PICTURE,),  # when the scene has a ground-truth mesh and the mesh step ran
    ),
}


# the steps whose ``sd15_*`` / ``compact_*`` params act only with that repair model (docs/repair.md); the
# weights step chooses the model (WeightsParams.chosen_model)
WEIGHTS_STEP = "go_pipeline.steps.weights"
REPAIR_MODEL_STEPS = ("go_pipeline.steps.tune", "go_pipeline.steps.repair")
MODEL_PREFIXES = {"sd15": "sd15_", "compact": "compact_"}


def only_model(module: str, param: str) -> str | None:
    """The repair model ("sd15" | "compact") that alone reads ``param`` of the step ``module``; None when
    the param acts with both (or the step is not one of REPAIR_MODEL_STEPS)."""
    if module not in REPAIR_MODEL_STEPS:
        return None
    return next((m for m, prefix in MODEL_PREFIXES.items() if param.startswith(prefix)), None)


def declaration(module: str) -> StepDeclaration | None:
    """The declaration of a packaged step module, or None for a step of your own."""
    return STEPS.get(module)


def params_class(module: str) -> type | None:
    found = STEPS.get(module)
    return None if found is None else found.params


def upstream_fields(cls: type) -> dict[str, type]:
    """Fields filled with another step's params: {field name: that step's params class}."""
    from go_core.config import field_types

    params_classes = {d.params for d in STEPS.values()}
    types = field_types(cls)
    return {f.name: types[f.name] for f in fields(cls) if types[f.name] in params_classes}
