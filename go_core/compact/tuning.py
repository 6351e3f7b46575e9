"""Per-scene tuning of the compact repair model on self-generated pairs (paper Sec. 3.4), resumable.

Each step draws one degraded/clean pair (Algorithm 1: ``go_core.repair.pairs.PairSource``), puts both in the
clean view's square frame at ``resolution`` and minimises L1(restore(degraded), clean) with Adam on every
weight of the network (a full fine-tune: the network has 0.6 M parameters; see docs/repair.md for the
measurement against smaller learning rates and no tuning). Checkpoints are one safetensors file each
(weights, Adam moments, torch RNG) with the rest (step, numpy RNG, pair schedule, loss log) as JSON
metadata: no pickle. A restarted run continues from the newest checkpoint and ends bit-identical (CPU).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from go_core.compact.restorer import CompactRestorer
from go_core.io.checkpoint import Checkpoints, CheckpointSpec, LossLog, fingerprint_of
from go_core.repair.pairs import Pair, pair_tensors
from go_core.seeding import numpy_rng, torch_generator

CKPT = ("compact_step", "compact-tune-1")  # checkpoint file prefix and format


@dataclass(frozen=True)
class CompactTuneSettings:
    """The compact tuning loop's knobs; the tune step fills them from its params (``compact_*``)."""

    steps: int
    lr: float
    betas: tuple[float, float]
    resolution: int
    checkpoint_every: int
    method: str  # "full": every weight; "lora": rank-``rank`` adapters on the convolutions (peft)
    rank: int
    log_every: int = 10
    region: str = "all"  # "inside": the RGB loss only inside the clean view's mask (a repair prior's alpha)

    def fingerprint(self, extra: str = "") -> str:
        return fingerprint_of({"s": asdict(self), "x": extra})


def pair_loss(
    model: CompactRestorer, degraded: torch.Tensor, clean: torch.Tensor, region: str = "all"
) -> torch.Tensor:
    """The tuning objective: L1 between the restored degraded image and the clean one (over every channel:
    with a repair prior the alpha too, against the clean view's mask). ``region="inside"`` (a repair prior
    only): the RGB term only where the clean mask is (weighted by it), the alpha term everywhere, so that the
    scene's views do not retrain what the prior does to the background."""
    restored = model(degraded)
    if region == "all":
        return F.l1_loss(restored, clean)
    if region != "inside" or clean.shape[1] != 4:
        raise ValueError(f"tune.compact_region {region!r}: 'all', or 'inside' with a repair prior's mask")
    mask = clean[:, 3:4]
    rgb = ((restored[:, :3] - clean[:, :3]).abs() * mask).sum() / (3.0 * mask.sum()).clamp_min(1.0)
    return (3.0 * rgb + F.l1_loss(restored[:, 3:4], mask)) / 4.0


@torch.no_grad()
def held_out_loss(model: CompactRestorer, pairs: list[tuple[torch.Tensor, torch.Tensor]]) -> float:
    """Mean tuning loss over fixed pairs (eval mode)."""
    was = model.training
    model.eval()
    try:
        return float(np.mean([float(pair_loss(model, d, c)) for d, c in pairs])) if pairs else float("nan")
    finally:
        model.train(was)


def _checkpoints(directory: Path | None, every: int) -> Checkpoints | None:
    return None if directory is None else Checkpoints(CheckpointSpec(Path(directory), every, keep=2), *CKPT)


def _restore(ckpts, fp: str, model, opt, names: list[str], gen, rng, schedule):
    """Load the newest checkpoint of this tuning into the model, the optimiser, the generators and the
    schedule; its (pair counts, step, loss entries, running loss), or None when there is none."""
    found = None if ckpts is None else ckpts.newest_tensors(fp)
    if found is None:
        return None
    tensors, meta = found
    model.load_state_dict({k[len("model.") :]: v for k, v in tensors.items() if k.startswith("model.")})
    if meta["adam_step"] > 0:
        state = opt.state_dict()
        state["state"] = {
            i: {
                "step": torch.tensor(float(meta["adam_step"])),
                "exp_avg": tensors[f"adam.{n}.exp_avg"],
                "exp_avg_sq": tensors[f"adam.{n}.exp_avg_sq"],
            }
            for i, n in enumerate(names)
        }
        opt.load_state_dict(state)
    gen.set_state(tensors["torch_rng"])
    rng.bit_generator.state = meta["np_rng"]
    schedule.load_state(meta["schedule"])
    return meta["counts"], int(meta["step"]), meta["losses"], meta["running"]


def _checkpoint(step: int, model, opt, names: list[str], params: list, state: tuple) -> tuple[dict, dict]:
    """(tensors, meta) of a checkpoint at ``step``: the model, Adam's moments, the generators, the
    schedule, the loss log and the pair counts (``state`` = generator, rng, schedule, log, counts)."""
    gen, rng, schedule, log, counts = state
    tensors = {f"model.{k}": v for k, v in model.state_dict().items()}
    for i, n in enumerate(names):
        st = opt.state[params[i]]
        tensors[f"adam.{n}.exp_avg"] = st["exp_avg"]
        tensors[f"adam.{n}.exp_avg_sq"] = st["exp_avg_sq"]
    tensors["torch_rng"] = gen.get_state()
    meta = {
        "adam_step": step,
        "np_rng": rng.bit_generator.state,
        "schedule": schedule.state(),
        "losses": log.entries,
        "counts": counts,
        "running": log.running,
    }
    return tensors, meta


def tune_compact(
    model: CompactRestorer,
    draw: Callable[[np.random.Generator, torch.Generator], Pair],
    schedule,
    settings: CompactTuneSettings,
    seed: int,
    checkpoint_dir: Path | None = None,
    on_step: Callable[[int, float], None] | None = None,
    fingerprint_extra: str = "",
) -> dict:
    """Fine-tune ``model`` in place on pairs from ``draw(rng, generator)``; ``schedule`` is the pair
    schedule whose state is checkpointed (``PairSchedule``). Returns a summary dict."""
    if settings.method == "lora" and not isinstance(model, CompactRestorer):
        raise ValueError("tune.compact_method 'lora' adapts a converted network; tune a repair prior 'full'")
    if settings.method == "lora":
        from go_core.compact.lora import add_conv_lora
        from go_core.extras import require_extra

        require_extra("sd15", "tune.compact_method lora (peft adapters)")

        add_conv_lora(model.net, settings.rank, seed)
    elif settings.method != "full":
        raise ValueError(f"compact tuning method must be 'full' or 'lora', got {settings.method!r}")
    trainable = [(n, p) for n, p in model.named_parameters() if p.requires_grad]
    params = [p for _, p in trainable]
    names = [n for n, _ in trainable]
    opt = torch.optim.Adam(params, lr=settings.lr, betas=tuple(settings.betas))
    gen = torch_generator(int(seed), "compact_noise")
    rng = numpy_rng(int(seed), "compact_batches")
    log = LossLog(settings.log_every, settings.steps)
    counts = {"noise": 0, "loo": 0}
    start = 0
    fp = settings.fingerprint(fingerprint_extra)
    ckpts = _checkpoints(checkpoint_dir, settings.checkpoint_every)
    resumed = _restore(ckpts, fp, model, opt, names, gen, rng, schedule)
    if resumed is not None:
        counts, start, losses, running = resumed
        log = LossLog(settings.log_every, settings.steps, losses, running)
    model.train()
    for step in range(start + 1, settings.steps + 1):
        pair = draw(rng, gen)
        counts[pair.kind] += 1
        deg, clean = pair_tensors(pair, settings.resolution, model.channels)
        loss = pair_loss(model, deg, clean, settings.region)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        value = float(loss.detach())
        log.add(step, value, p_manual=round(schedule.p, 6))
        if on_step is not None:
            on_step(step, value)
        if ckpts is not None and ckpts.due(step, settings.steps):
            state = (gen, rng, schedule, log, counts)
            ckpts.save_tensors(step, fp, *_checkpoint(step, model, opt, names, params, state))
    if settings.method == "lora":
        from go_core.compact.lora import merge_conv_lora

        merge_conv_lora(model.net)
    model.eval()
    return {
        "steps": settings.steps,
        "loss_log": log.entries,
        "pairs_used": counts,
        "p_manual_final": schedule.p,
        "resumed_from": start,
    }
