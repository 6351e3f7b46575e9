"""repair: Gaussian repair with the (LoRA-tuned) repair model along distance-aware paths (paper Sec. 3.5).

4000 iterations from the coarse model: the reference views with the coarse-stage loss throughout; during the
first 2800 also L_rep = decay · w(t) · λ(π) · (L1 + L2 + LPIPS) on repaired novel views (decay 1.0 → 0.1)
drawn from the middle 80% of the arcs between reference views on the ellipse of the TRAINING cameras
(test cameras never shape a path); repaired images refreshed every 200 iterations, two per arc; the
authors' densification schedule (every 100 from 400 to 3600, opacity reset every 500, prune below 0.02).

Skips honestly (``repair.json`` ``{"status": "skipped", "reason": ...}``, no ``gaussians.npz``; downstream
steps then use the coarse model) when the tune step had no weights, or for the "no repair" ablation
(``mode: no_repair``). ``use_lora: false`` is the "no fine-tuning" ablation (pretrained ControlNet only);
``loss: sds`` replaces L_rep by score distillation on the same paths (the "SDS" ablation row).
The LPIPS term uses go_core.metrics' LPIPS (``lpips_net``) when its weights are installed, else it is off
and ``repair.json`` says so.

With the compact repair model (``tune.json`` ``"repair_model": "compact"``): the tuned restorer from the tune
step (``compact.safetensors``; the pretrained one with ``use_lora: false`` or after ``finetune: false``)
repairs each novel view in one pass at ``compact_resolution``; the SDEdit strength t becomes a blend
strength b ~ U(``strength_range``) with w = b (go_core.repair.repair). ``loss: sds`` needs sd15.

Outputs: ``repair.json``; with status ok also ``gaussians.npz`` and ``repair_preview.png`` (render | repaired
for the last refresh's views).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from go_core import artifacts as art
from go_core.errors import GoError, first_line
from go_core.io.atomic import atomic_write
from go_core.io.curves import write_curves
from go_pipeline.steps._common import write_skipped

if TYPE_CHECKING:
    from go_pipeline.steps.params import RepairParams


def _compact_engine(inputs: dict[str, Path], tune_info: dict, use_lora: bool, device: str):
    """(CompactRepair, "fine-tuned" | "pretrained (no fine-tuning)") from the tune step's artifact."""
    from safetensors.torch import load_file

    from go_core.compact.engine import CompactRepair
    from go_core.compact.restorer import CompactRestorer

    restorer = CompactRestorer.load(tune_info["compact"]["name"])  # one clear error when absent/corrupt
    tuned = use_lora and tune_info.get("status") == "ok"
    if tuned:
        restorer.net.load_ncnn_tensors(load_file(str(Path(inputs["tune"]) / tune_info["tuned"])))
    return CompactRepair(restorer, device), "fine-tuned" if tuned else "pretrained (no fine-tuning)"


def _lpips(net: str, weight: float):
    """(callable or None, note) — the differentiable LPIPS of go_core.metrics when its weights exist."""
    if weight <= 0:
        return None, "off (weight 0)"
    try:
        from go_core.metrics.lpips import LPIPS

        model = LPIPS.from_cache(net)
    except (GoError, OSError, KeyError, RuntimeError) as exc:
        return None, f"off: LPIPS-{net} weights unavailable ({first_line(exc)})"
    return (lambda a, b: model(a * 2.0 - 1.0, b * 2.0 - 1.0)), f"on (LPIPS-{net})"


def _preview(path: Path, cache, size: int = 128) -> None:
    import numpy as np
    from PIL import Image

    from go_core.io.images import thumbnail

    rows = [
        np.concatenate([thumbnail(v.render, size), thumbnail(v.image, size)], axis=1) for v in cache.views
    ]
    if not rows:
        return
    width = max(r.shape[1] for r in rows)
    sheet = np.concatenate(
        [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    )
    atomic_write(path, lambda tmp: Image.fromarray(sheet).save(tmp, format="PNG"))


def run(ctx, inputs: dict[str, Path], params: RepairParams) -> None:

    from go_core.diffusion.lora import add_lora, load_lora_state_dict, read_lora
    from go_core.diffusion.models import (
        WeightPaths,
        load_repair_models,
        precision_dtypes,
    )
    from go_core.diffusion.sampler import RepairDiffusion
    from go_core.repair.data import training_views
    from go_core.repair.repair import repair_gaussians

    mode = params.mode
    if mode == "no_repair":
        write_skipped(ctx, art.REPAIR_INFO, "ablation: no repair (mode no_repair)")
        return
    tune_info = art.read_json(inputs["tune"], art.TUNE_INFO)  # a skipped tune step skips this one (registry)
    device = str(ctx.device)
    repair_model = str(tune_info.get("repair_model", "sd15"))
    settings = params  # RepairSettings with the coarse step's settings (params.coarse)
    if repair_model == "compact":
        if settings.loss == "sds":
            raise GoError("repair.loss 'sds' needs the sd15 repair model (weights.repair_model)")
        diffusion, lora_note = _compact_engine(inputs, tune_info, params.use_lora, device)
        res = params.compact_resolution
        if res % diffusion.restorer.scale:
            raise GoError(
                f"repair.compact_resolution must be a multiple of {diffusion.restorer.scale}, got {res}"
            )
        settings = replace(settings, resolution=res, lpips=params.compact_lpips)
    else:
        paths = WeightPaths(**tune_info["weights"])
        weight_dtype, autocast_dtype = precision_dtypes(device, params.precision)
        models = load_repair_models(paths, device=device, dtype=weight_dtype)  # moved/broken weights raise
        use_lora = params.use_lora and tune_info.get("status") == "ok"
        if use_lora:
            spec, state = read_lora(Path(inputs["tune"]) / tune_info["lora"])
            add_lora(models, spec)
            load_lora_state_dict(models, spec, state)
            for m in models.modules().values():
                m.to(device)
        diffusion = RepairDiffusion(
            models,
            prompt=str(tune_info.get("prompt", "a photo of xxy5syt00")),
            device=device,
            autocast_dtype=autocast_dtype,
            guidance_scale=params.guidance_scale,
        )
        lora_note = "fine-tuned" if use_lora else "pretrained (no fine-tuning)"
    lpips, lpips_note = _lpips(params.lpips_net, settings.lpips)
    _, views = training_views(inputs["scene"], inputs.get("mask"), inputs["coarse"])
    coarse = art.read_gaussians(inputs["coarse"])
    bar: dict = {}

    def advance(step: int, info: dict) -> None:
        """Progress bar created at the first step run, so a resumed run starts at its checkpoint."""
        if "p" not in bar:
            bar["p"] = ctx.progress(settings.iterations, "Gaussian repair", completed=step - 1)
        bar["p"].advance(1, loss=info.get("loss"), gaussians=info.get("n"))

    result, summary, facts = repair_gaussians(
        coarse,
        views,
        diffusion,
        settings,
        ctx.seed,
        checkpoint_dir=Path(ctx.checkpoint_dir),
        lpips=lpips,
        on_progress=advance,
    )
    if "p" in bar:
        bar["p"].close()
    out = Path(ctx.out_dir)
    art.write_gaussians(out, result)
    write_curves(art.CURVES.path(out), facts["loss_log"])  # loss, train PSNR, Gaussians per logged step
    _preview(art.REPAIR_PREVIEW.path(out), facts["cache"])
    info = {
        "status": "ok",
        "mode": mode,
        "loss": settings.loss,
        "repair_model": repair_model,
        "compact_model": tune_info["compact"]["name"] if repair_model == "compact" else "",
        "lora": lora_note,
        "lpips_term": lpips_note,
        "device": device,
        "count": len(result),
        **summary,
    }
    art.write_json(out, art.REPAIR_INFO, info)
    ctx.record(
        status="ok",
        repair_model=repair_model,
        lora=info["lora"],
        lpips_term=lpips_note,
        count=len(result),
        resumed_from=facts["resumed_from"],
        refreshes_made=facts["refreshes_made"],
        l_rep_last=facts["l_rep_log"][-3:],
    )
