"""tune: fine-tune the repair model on the scene's self-generated pairs (SD1.5: LoRA).

LoRA rank 64 (peft) on the UNet's and the ControlNet's transformer blocks and the CLIP text encoder's
attention; AdamW lr 1e-3, β (0.9, 0.999), 1800 steps, batch 1, prompt "a photo of xxy5syt00"; ε-prediction
MSE with the degraded image as ControlNet condition and the clean reference as target (paper Sec. 3.4).
Pairs: Algorithm 1 (noise pairs on the fly, else leave-one-out pairs). Checkpoints into ctx.checkpoint_dir
every ``checkpoint_every`` steps; a killed step resumes from the newest one.

Weights come from the ``weights`` step (local paths from its params or $GO_SD15_PATH /
$GO_CONTROLNET_TILE_PATH / $GO_CLIP_PATH / $GO_SD15_CONFIG). When none is configured the runner skips the
step (steps/registry.py): ``tune.json`` says ``{"status": "skipped", "reason": ...}`` and the repair step (and
so the report) falls back to the coarse model. Paths given but wrong already failed in the weights step
(MissingWeightsError); files that exist but cannot be loaded raise here.
``finetune: false`` is the "no fine-tuning" ablation: ``status: "pretrained"`` (the repair step then uses the
pretrained ControlNet without LoRA).

Outputs: ``tune.json``; with status ok also ``lora.safetensors`` (only the LoRA tensors).

With the compact repair model (``weights.repair_model``): a full fine-tune of the pretrained restorer on the
same Algorithm-1 pairs (go_core.compact.tuning: L1, Adam ``compact_lr``, ``compact_steps`` steps at
``compact_resolution``), checkpointed as safetensors; writes ``compact.safetensors`` (the tuned network)
and records the loss on the leave-one-out pairs before and after tuning. With ``prior_choice`` naming a
repair prior, that restorer is first tuned once per training view on the other views' pairs and scored,
with the prior as shipped, on the held-out view's leave-one-out pairs; where the prior scores higher it
repairs untuned (``status: "pretrained"``, tune.json ``choice``; steps/_repair_models.py
``restorer_choice``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from go_pipeline.steps._repair_models import repair_model_named
from go_pipeline.steps.weights import repair_model

if TYPE_CHECKING:
    from go_pipeline.steps.params import TuneParams


def run(ctx, inputs: dict[str, Path], params: TuneParams) -> None:
    """Tune the repair model the weights step chose (steps/_repair_models.py: compact or sd15)."""
    repair_model_named(repair_model(inputs)).tune(ctx, inputs, params)
