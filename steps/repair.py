"""repair: Gaussian repair with the (LoRA-tuned) repair model along distance-aware paths (paper Sec. 3.5).

4000 iterations from the coarse model: the reference views with the coarse-stage loss throughout; during the
first 2800 also L_rep = decay · w(t) · λ(π) · (L1 + L2 + LPIPS) on repaired novel views (decay 1.0 → 0.1)
drawn from the middle 80% of the arcs between reference views on the ellipse of the TRAINING cameras
(test cameras never shape a path); repaired images refreshed every 200 iterations, two per arc; the
authors' densification schedule (every 100 from 400 to 3600, prune below 0.02; no opacity reset, which
``repair.opacity_reset_every`` can turn on).

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

With ``consensus`` (the default) the step first makes a second model of the scene, the coarse fit and this
repair at ``derive_seed(seed, "consensus")`` (go_core.repair.second_model, each phase resumable under the
checkpoint folder's ``consensus/``), and each novel view's repair input is then what both models render
(go_core.repair.consensus); ``repair.json`` ``"consensus"`` names its seed, member and Gaussian counts.
``consensus_models`` above 2 adds further models the same way (seeds ``derive_seed(seed, "consensus-3")``,
..., folders ``consensus-3/``, ...), and the input is what all of them render.
``consensus_member: coarse`` skips the second model's repair (its coarse fit is the second model).

Outputs: ``repair.json``; with status ok also ``gaussians.npz`` and ``repair_preview.png`` (render | repaired
for the last refresh's views).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from go_pipeline.steps._common import ResumedProgress, write_skipped
from go_pipeline.steps._repair_models import compact_engine, repair_model_named

from go_core import artifacts as art
from go_core.errors import GoError, first_line
from go_core.io.atomic import atomic_write
from go_core.io.curves import write_curves

if TYPE_CHECKING:
    from go_pipeline.steps.params import RepairParams


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


def _consensus_members(ctx, scene_inputs, params: RepairParams, diffusion, settings, lpips) -> list:
    """The consensus's further models (go_core.repair.second_model), ``consensus_models`` - 1 of them, of
    ``scene_inputs`` (the coarse stage's inputs, go_core.coarse.fit.CoarseInputs): each the coarse fit and
    (consensus_member repaired) the plain repair at its own derived seed, resumable phase by phase under the
    step's checkpoint folder (``consensus/``, ``consensus-3/``, ...)."""
    from go_core.repair.second_model import member_tag, second_model

    members = []
    for number in range(2, params.consensus_models + 1):
        name = "second" if number == 2 else f"model {number}'s"
        bars = {"coarse": ResumedProgress(ctx, params.coarse.iterations, f"consensus: {name} coarse 3DGS")}
        if params.consensus_member == "repaired":
            bars["repair"] = ResumedProgress(ctx, settings.iterations, f"consensus: {name} Gaussian repair")
        member = second_model(
            scene_inputs,
            params.coarse.scaled_schedule(),
            params.coarse.checkpoint_every,
            diffusion,
            settings,
            ctx.seed,
            Path(ctx.checkpoint_dir) / member_tag(number),
            lpips,
            lambda phase, step, info, bars=bars: bars[phase].advance(
                step, loss=info.get("loss"), gaussians=info.get("n")
            ),
            member=params.consensus_member,
            number=number,
        )
        for bar in bars.values():
            bar.close()
        members.append(member)
    return members


def _consensus_record(members: list, restorer: str) -> dict:
    """repair.json's ``consensus``: the second model's seed, member and counts, its restorer, how many models
    agree, and (more than two) the further models' seeds and counts."""
    record = {**members[0].summary(), "restorer": restorer or "own"}
    record["models"] = len(members) + 1
    if len(members) > 1:
        record["further"] = [m.summary() for m in members[1:]]
    return record


def consensus_restorer_name(params: RepairParams, tune_info: dict) -> str:
    """The second model's restorer: ``repair.consensus_restorer``, where 'choice' is the tune step's
    (tune.json's ``choice`` → ``consensus_restorer``; '' when it made no choice): '' for the run's own."""
    if params.consensus_restorer != "choice":
        return params.consensus_restorer
    return str((tune_info.get("choice") or {}).get("consensus_restorer", ""))


def _consensus_restorer(name: str, params: RepairParams, repair_model: str, device: str):
    """The engine that repairs the second model when ``name`` (consensus_restorer_name) names one: that
    compact model as shipped (a repair prior: its alpha and reference inputs come with it); None for the
    run's own (tuned). Resolved before the run's own model is loaded, so a wrong choice fails before any
    heavy load."""
    if not (params.consensus and name):
        return None
    if repair_model != "compact":
        raise GoError(
            f"repair.consensus_restorer {name!r} needs the compact repair model; the run's is "
            f"{repair_model!r}"
        )
    return compact_engine(name, device)  # as shipped; missing or corrupt weights: one clear error


def run(ctx, inputs: dict[str, Path], params: RepairParams) -> None:
    from go_core.coarse.fit import coarse_inputs
    from go_core.repair.data import repair_views
    from go_core.repair.repair import repair_gaussians

    mode = params.mode
    if mode == "no_repair":
        write_skipped(ctx, art.REPAIR_INFO, "ablation: no repair (mode no_repair)")
        return
    tune_info = art.read_json(inputs["tune"], art.TUNE_INFO)  # a skipped tune step skips this one (registry)
    device = str(ctx.device)
    repair_model = str(tune_info.get("repair_model", "sd15"))
    second_name = consensus_restorer_name(params, tune_info)
    second_restorer = _consensus_restorer(second_name, params, repair_model, device)
    # RepairSettings with the coarse step's settings (params.coarse), as the model needs them
    diffusion, lora_note, settings = repair_model_named(repair_model).load(inputs, tune_info, params, device)
    lpips, lpips_note = _lpips(params.lpips_net, diffusion.lpips_weight(settings))
    # the scene read once: the coarse stage's inputs, for this repair's views and the second model's fit
    scene_inputs = coarse_inputs(inputs["scene"], inputs["mask"], inputs["hull"], inputs.get("depth"))
    views = repair_views(scene_inputs.views, inputs["coarse"])
    coarse = art.read_gaussians(inputs["coarse"])
    members = []
    if params.consensus:
        restorer = diffusion if second_restorer is None else second_restorer
        members = _consensus_members(ctx, scene_inputs, params, restorer, settings, lpips)
    bar = ResumedProgress(ctx, settings.iterations, "Gaussian repair")

    result, summary, facts = repair_gaussians(
        coarse,
        views,
        diffusion,
        settings,
        ctx.seed,
        checkpoint_dir=Path(ctx.checkpoint_dir),
        lpips=lpips,
        on_progress=lambda step, info: bar.advance(step, loss=info.get("loss"), gaussians=info.get("n")),
        consensus=[m.gaussians for m in members],
    )
    bar.close()
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
        "consensus": _consensus_record(members, second_name) if members else "off",
        **summary,
    }
    art.write_json(out, art.REPAIR_INFO, info)
    ctx.record(
        status="ok",
        repair_model=repair_model,
        lora=info["lora"],
        lpips_term=lpips_note,
        count=len(result),
        consensus=info["consensus"],
        resumed_from=facts["resumed_from"],
        refreshes_made=facts["refreshes_made"],
        l_rep_last=facts["l_rep_log"][-3:],
    )
