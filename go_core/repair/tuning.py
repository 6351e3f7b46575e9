"""Fine-tuning the repair model with LoRA on degraded/clean pairs (paper Sec. 3.4), resumable.

Per step (batch 1): draw a pair (Algorithm 1, ``pairs.PairSource``), put both images in the clean view's
square frame at ``resolution``, and minimise the ε-prediction MSE of the UNet + ControlNet (conditioned on
the degraded image, prompt "a photo of xxy5syt00") for the clean image's noised latent. AdamW on the LoRA
tensors only. Checkpoints (LoRA tensors, optimiser, both RNG states, pair schedule, loss log) every
``checkpoint_every`` steps; a restarted run continues from the newest one and ends bit-identical (CPU).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import torch

from go_core.diffusion.lora import LoraSpec, load_lora_state_dict, lora_parameters, lora_state_dict
from go_core.diffusion.sampler import RepairDiffusion
from go_core.repair.pairs import PairSource, pair_tensors
from go_core.seeding import numpy_rng, torch_generator

CKPT_FORMAT = 1


@dataclass(frozen=True)
class TuneSettings:
    steps: int = 1800
    lr: float = 1e-3
    betas: tuple[float, float] = (0.9, 0.999)
    weight_decay: float = 1e-2
    resolution: int = 512
    checkpoint_every: int = 300
    log_every: int = 10

    def fingerprint(self, spec: LoraSpec, extra: str = "") -> str:
        blob = json.dumps({"s": asdict(self), "l": asdict(spec), "x": extra}, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _newest(directory: Path, fingerprint: str) -> dict | None:
    from go_core.io.checkpoint import try_load_checkpoint

    if not directory.is_dir():
        return None
    for path in sorted(directory.glob("lora_step_*.pt"), reverse=True):
        payload = try_load_checkpoint(path)  # tensors and plain containers only: never code
        if not isinstance(payload, dict):
            continue
        if payload.get("format") == CKPT_FORMAT and payload.get("fingerprint") == fingerprint:
            return payload
    return None


def _save(directory: Path, payload: dict, keep: int = 2) -> None:
    from go_core.io.atomic import atomic_torch_save

    directory.mkdir(parents=True, exist_ok=True)
    atomic_torch_save(directory / f"lora_step_{payload['step']:07d}.pt", payload)
    for old in sorted(directory.glob("lora_step_*.pt"))[:-keep]:
        old.unlink(missing_ok=True)


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
    losses: list[dict] = []
    counts = {"noise": 0, "loo": 0}
    start = 0
    running = 0.0
    fp = settings.fingerprint(spec, fingerprint_extra)
    if checkpoint_dir is not None:
        payload = _newest(Path(checkpoint_dir), fp)
        if payload is not None:
            load_lora_state_dict(diffusion.models, spec, payload["lora"])
            opt.load_state_dict(payload["optimizer"])
            gen.set_state(payload["torch_rng"])
            rng.bit_generator.state = payload["np_rng"]
            source.schedule.load_state(payload["schedule"])
            losses, counts, start = payload["losses"], payload["counts"], int(payload["step"])
            running = float(payload.get("running", 0.0))
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
        running += value
        if step % max(settings.log_every, 1) == 0 or step == settings.steps:
            n = step % max(settings.log_every, 1) or max(settings.log_every, 1)
            losses.append(
                {"step": step, "loss": round(running / n, 6), "p_manual": round(source.schedule.p, 6)}
            )
            running = 0.0
        if on_step is not None:
            on_step(step, value)
        if (
            checkpoint_dir is not None
            and settings.checkpoint_every > 0
            and step % settings.checkpoint_every == 0
            and step < settings.steps
        ):
            _save(
                Path(checkpoint_dir),
                {
                    "format": CKPT_FORMAT,
                    "fingerprint": fp,
                    "step": step,
                    "lora": lora_state_dict(diffusion.models, spec),
                    "optimizer": opt.state_dict(),
                    "torch_rng": gen.get_state(),
                    "np_rng": rng.bit_generator.state,
                    "schedule": source.schedule.state(),
                    "losses": losses,
                    "counts": counts,
                    "running": running,
                },
            )
    for m in ("unet", "controlnet", "text_encoder"):
        getattr(diffusion.models, m).eval()
    return {
        "steps": settings.steps,
        "loss_log": losses,
        "pairs_used": counts,
        "p_manual_final": source.schedule.p,
        "resumed_from": start,
    }
