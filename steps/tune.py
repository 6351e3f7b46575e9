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
and records the loss on the leave-one-out pairs before and after tuning.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

from go_core import artifacts as art
from go_pipeline.steps.weights import compact_info, repair_model, weight_paths

if TYPE_CHECKING:
    from go_pipeline.steps.params import TuneParams


def _pair_source(inputs: dict[str, Path], params: TuneParams, views):
    """Algorithm 1's pair source over the coarse model, the noise statistics and the leave-one-out pairs."""
    from go_core.repair.noise import NoiseStats
    from go_core.repair.pairs import LooPairs, PairSource

    noise_cfg = art.read_json(inputs["noise_pairs"], art.NOISE_PAIRS_INFO)
    coarse = art.read_gaussians(inputs["coarse"])
    loo = LooPairs(inputs["loo"]) if params.use_loo_pairs else None
    return PairSource(
        coarse,
        NoiseStats.from_json(noise_cfg["stats"]),
        views,
        loo,
        p0=float(noise_cfg["p0"]),
        decay=float(noise_cfg["decay"]),
        backend=params.backend,
        noise_scale=float(noise_cfg["noise_scale"]),
    )


def _run_compact(ctx, inputs: dict[str, Path], params: TuneParams) -> None:
    """Per-scene full fine-tune of the compact restorer (see the module docstring)."""
    from go_core.compact.restorer import CompactRestorer
    from go_core.compact.tuning import CompactTuneSettings, held_out_loss, tune_compact
    from go_core.io.safetensors_file import write_safetensors
    from go_core.repair.data import training_views
    from go_core.repair.pairs import LooPairs, pair_tensors

    info = compact_info(inputs)
    model = CompactRestorer.load(info["name"])  # missing or corrupt weights: one MissingWeightsError
    base = {"repair_model": "compact", "compact": info}
    if not params.finetune:
        art.write_json(
            ctx.out_dir,
            art.TUNE_INFO,
            {**base, "status": "pretrained", "reason": "ablation: no fine-tuning (pretrained restorer only)"},
        )
        ctx.record(status="pretrained", repair_model="compact", reason="ablation: no fine-tuning")
        return
    settings = CompactTuneSettings(
        steps=params.compact_steps,
        lr=params.compact_lr,
        betas=params.betas,
        resolution=params.compact_resolution,
        checkpoint_every=params.checkpoint_every,
        method=params.compact_method,
        rank=params.compact_rank,
    )
    if settings.resolution % model.scale:
        raise ValueError(
            f"tune.compact_resolution must be a multiple of {model.scale}, got {settings.resolution}"
        )
    _, views = training_views(inputs["scene"], inputs.get("mask"), inputs["coarse"])
    source = _pair_source(inputs, params, views)
    loo = LooPairs(inputs["loo"])
    loo_pairs = [pair_tensors(loo.get(i), settings.resolution) for i in range(len(loo))]
    before = held_out_loss(model, loo_pairs)
    bar: dict = {}

    def advance(step: int) -> None:
        if "p" not in bar:
            bar["p"] = ctx.progress(settings.steps, "compact tuning", completed=step - 1)
        bar["p"].advance()

    summary = tune_compact(
        model, source.draw, source.schedule, settings, ctx.seed, Path(ctx.checkpoint_dir),
        on_step=lambda step, loss: advance(step), fingerprint_extra=info["sha256"],
    )  # fmt: skip
    if "p" in bar:
        bar["p"].close()
    after = held_out_loss(model, loo_pairs)
    resumed_from = summary.pop("resumed_from")
    tensors = {k: v.contiguous() for k, v in model.net.ncnn_tensors().items()}
    meta = {"name": info["name"], "base_sha256": info["sha256"], "tuned_steps": str(settings.steps)}
    write_safetensors(art.COMPACT_WEIGHTS.path(ctx.out_dir), tensors, meta)
    out = {
        **base,
        "status": "ok",
        "tuned": art.COMPACT_WEIGHTS.file,
        "method": "full fine-tune (L1, Adam)"
        if settings.method == "full"
        else f"LoRA rank {settings.rank} on the convolutions, merged (L1, Adam)",
        "settings": asdict(settings),
        "loo_pairs_l1": {"before": round(before, 6), "after": round(after, 6), "pairs": len(loo_pairs)},
        **summary,
    }
    art.write_json(ctx.out_dir, art.TUNE_INFO, out)
    log = summary["loss_log"]
    ctx.record(
        status="ok", repair_model="compact", steps=settings.steps, resumed_from=resumed_from,
        loss_first=log[0]["loss"] if log else None, loss_last=log[-1]["loss"] if log else None,
        loo_pairs_l1_before=round(before, 6), loo_pairs_l1_after=round(after, 6),
        pairs_used=summary["pairs_used"],
    )  # fmt: skip


def run(ctx, inputs: dict[str, Path], params: TuneParams) -> None:

    from go_core.diffusion.lora import LoraSpec, add_lora, save_lora
    from go_core.diffusion.models import load_repair_models, precision_dtypes
    from go_core.diffusion.sampler import RepairDiffusion
    from go_core.repair.data import training_views
    from go_core.repair.tuning import TuneSettings, tune

    if repair_model(inputs) == "compact":
        _run_compact(ctx, inputs, params)
        return
    paths = weight_paths(inputs)
    weights = paths.describe()
    prompt = params.prompt
    if not params.finetune:
        art.write_json(
            ctx.out_dir,
            art.TUNE_INFO,
            {
                "status": "pretrained",
                "reason": "ablation: no fine-tuning (pretrained ControlNet only)",
                "weights": weights,
                "prompt": prompt,
            },
        )
        ctx.record(status="pretrained", reason="ablation: no fine-tuning")
        return

    device = str(ctx.device)
    weight_dtype, autocast_dtype = precision_dtypes(device, params.precision)
    models = load_repair_models(paths, device=device, dtype=weight_dtype)  # unreadable files raise
    spec = LoraSpec(
        rank=params.rank,
        alpha=params.alpha,
        unet=params.unet,
        controlnet=params.controlnet,
        text_encoder=params.text_encoder,
    )
    counts = add_lora(models, spec, seed=int(ctx.seed))
    diffusion = RepairDiffusion(models, prompt=prompt, device=device, autocast_dtype=autocast_dtype)

    _, views = training_views(inputs["scene"], inputs.get("mask"), inputs["coarse"])
    source = _pair_source(inputs, params, views)
    settings = TuneSettings(
        steps=params.steps,
        lr=params.lr,
        betas=params.betas,
        weight_decay=params.weight_decay,
        resolution=params.resolution,
        checkpoint_every=params.checkpoint_every,
    )
    bar: dict = {}

    def advance(step: int, loss: float) -> None:
        """Progress bar created at the first step run, so a resumed run starts at its checkpoint."""
        if "p" not in bar:
            bar["p"] = ctx.progress(settings.steps, "LoRA tuning", completed=step - 1)
        bar["p"].advance(1, loss=loss)

    summary = tune(
        diffusion,
        spec,
        source,
        settings,
        ctx.seed,
        checkpoint_dir=Path(ctx.checkpoint_dir),
        on_step=advance,
        fingerprint_extra=device,
    )
    if "p" in bar:
        bar["p"].close()
    resumed_from = summary.pop("resumed_from")
    save_lora(art.LORA_WEIGHTS.path(ctx.out_dir), models, spec, extra={"prompt": prompt})
    info = {
        "status": "ok",
        "weights": weights,
        "prompt": prompt,
        "lora": art.LORA_WEIGHTS.file,
        "spec": asdict(spec),
        "lora_parameters": counts,
        "settings": asdict(settings),
        "device": device,
        "precision": str(weight_dtype).replace("torch.", ""),
        **summary,
    }
    art.write_json(ctx.out_dir, art.TUNE_INFO, info)
    log = summary["loss_log"]
    ctx.record(
        status="ok",
        steps=settings.steps,
        resumed_from=resumed_from,
        loss_first=log[0]["loss"] if log else None,
        loss_last=log[-1]["loss"] if log else None,
        pairs_used=summary["pairs_used"],
        lora_parameters=sum(counts.values()),
    )
