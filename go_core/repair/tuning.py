"""Fine-tuning the repair model with LoRA on degraded/clean pairs (paper Sec. 3.4), resumable.

Per step (batch 1): draw a pair (Algorithm 1, ``pairs.PairSource``), put both images in the clean view's
square frame at ``resolution``, and minimise the ε-prediction MSE of the UNet + ControlNet (conditioned on
the degraded image, prompt "a photo of xxy5syt00") for the clean image's noised latent. AdamW on the LoRA
tensors only. Checkpoints (LoRA tensors, optimiser, both RNG states, pair schedule, loss log) every
``checkpoint_every`` steps; a restarted run continues from the newest one and ends bit-identical (CPU).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import torch

from go_core.diffusion.lora import LoraSpec, load_lora_state_dict, lora_parameters, lora_state_dict
from go_core.diffusion.sampler import RepairDiffusion
from go_core.io.checkpoint import Checkpoints, CheckpointSpec, LossLog, fingerprint_of
from go_core.repair.pairs import PairSource, pair_tensors
from go_core.seeding import numpy_rng, torch_generator

CKPT = ("lora_step", 1)  # checkpoint file prefix and format


@dataclass(frozen=True)
class TuneSettings:
    """The tuning loop's knobs; the tune step fills them from its params (whose defaults are the paper's)."""

    steps: int
    lr: float
    betas: tuple[float, float]
    weight_decay: float
    resolution: int
    checkpoint_every: int
    log_every: int = 10

    def fingerprint(self, spec: LoraSpec, extra: str = "") -> str:
        return fingerprint_of({"s": asdict(self), "l": asdict(spec), "x": extra})


def _checkpoints(directory: Path | None, every: int) -> Checkpoints | None:
    return None if directory is None else Checkpoints(CheckpointSpec(Path(directory), every, keep=2), *CKPT)


def tune(
    diffusion: RepairDiffusion,
    spec: LoraSpec,
    source: PairSource,
    settings: TuneSettings,
    seed: int,
    checkpoint_dir: Path | None = None,
    on_step: Callable[[int, float], None] | None = None,
    fingerprint_extra: str = "",
) -> dict:
    """Train the LoRA tensors already injected into ``diffusion.models``; returns a summary dict."""
    params = lora_parameters(diffusion.models)
    opt = torch.optim.AdamW(
        params, lr=settings.lr, betas=tuple(settings.betas), weight_decay=settings.weight_decay
    )
    gen = torch_generator(int(seed), "lora_noise")
    rng = numpy_rng(int(seed), "lora_batches")
    log = LossLog(settings.log_every, settings.steps)
    counts = {"noise": 0, "loo": 0}
    start = 0
    fp = settings.fingerprint(spec, fingerprint_extra)
    ckpts = _checkpoints(checkpoint_dir, settings.checkpoint_every)
    payload = ckpts.newest(fp) if ckpts is not None else None
    if payload is not None:
        load_lora_state_dict(diffusion.models, spec, payload["lora"])
        opt.load_state_dict(payload["optimizer"])
        gen.set_state(payload["torch_rng"])
        rng.bit_generator.state = payload["np_rng"]
        source.schedule.load_state(payload["schedule"])
        counts, start = payload["counts"], int(payload["step"])
        log = LossLog(settings.log_every, settings.steps, payload["losses"], float(payload["running"]))
    for m in ("unet", "controlnet", "text_encoder"):
        getattr(diffusion.models, m).train()
    for step in range(start + 1, settings.steps + 1):
        pair = source.draw(rng, gen)
        counts[pair.kind] += 1
        deg, clean = pair_tensors(pair, settings.resolution)
        loss = diffusion.tuning_loss(deg, clean, gen)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        value = float(loss.detach())
        log.add(step, value, p_manual=round(source.schedule.p, 6))
        if on_step is not None:
            on_step(step, value)
        if ckpts is not None and ckpts.due(step, settings.steps):
            ckpts.save(
                step,
                fp,
                {
                    "lora": lora_state_dict(diffusion.models, spec),
                    "optimizer": opt.state_dict(),
                    "torch_rng": gen.get_state(),
                    "np_rng": rng.bit_generator.state,
                    "schedule": source.schedule.state(),
                    "losses": log.entries,
                    "counts": counts,
                    "running": log.running,
                },
            )
    for m in ("unet", "controlnet", "text_encoder"):
        getattr(diffusion.models, m).eval()
    return {
        "steps": settings.steps,
        "loss_log": log.entries,
        "pairs_used": counts,
        "p_manual_final": source.schedule.p,
        "resumed_from": start,
    }
