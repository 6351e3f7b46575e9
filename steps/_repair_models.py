"""One interface to the two repair models (docs/repair.md), so the tune and repair steps never branch on
which one runs: ``tune`` (the tune step: fit the model to the scene's Algorithm-1 pairs, write ``tune.json``
and the tuned weights), ``load`` (the repair step: the tuned model as the repair loop's engine, the note the
report shows and the repair settings it needs) and the engine's ``restore`` (the repair loop: one repaired
view; go_core.compact.engine.CompactRepair, go_core.diffusion.sampler.RepairDiffusion). Implementations:
``CompactModel`` (a pretrained one-pass restorer, fully fine-tuned) and ``SD15Model`` (SD1.5 +
ControlNet-tile + CLIP with LoRA, the paper's).
"""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from go_pipeline.steps._common import ResumedProgress
from go_pipeline.steps.weights import compact_info, compact_model_info, weight_paths

from go_core import artifacts as art
from go_core.errors import GoError

if TYPE_CHECKING:
    from go_pipeline.steps.params import RepairParams, TuneParams


class RepairModel(Protocol):
    name: str  # "compact" | "sd15", as weights.json and tune.json record it

    def tune(self, ctx, inputs: dict[str, Path], params: TuneParams) -> None:
        """Fit the model to the scene's pairs; write ``tune.json`` (and the weights) into ``ctx.out_dir``."""
        ...

    def load(
        self, inputs: dict[str, Path], tune_info: dict, params: RepairParams, device: str
    ) -> tuple[Any, str, RepairParams]:
        """(engine with ``restore``, "fine-tuned" | "pretrained (no fine-tuning)", the repair settings)."""
        ...


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


def compact_tune_settings(params: TuneParams):
    """The compact tuning's settings (go_core.compact.tuning.CompactTuneSettings) from the tune step's."""
    from go_core.compact.tuning import CompactTuneSettings

    return CompactTuneSettings(
        steps=params.compact_steps,
        lr=params.compact_lr,
        betas=params.betas,
        resolution=params.compact_resolution,
        checkpoint_every=params.checkpoint_every,
        method=params.compact_method,
        rank=params.compact_rank,
        region=params.compact_region,
    )


def fold_tune_settings(params: TuneParams):
    """A held-out fold's tuning settings: the final tuning's, for ``choice_steps`` steps at most (a fold only
    has to rank the tuned restorer against the prior, not to be the restorer that repairs)."""
    settings = compact_tune_settings(params)
    return replace(settings, steps=min(params.choice_steps, settings.steps))


class CompactModel:
    """The compact restorer: a full fine-tune (or LoRA on its convolutions) with L1 and Adam."""

    name = "compact"

    def tune(self, ctx, inputs: dict[str, Path], params: TuneParams) -> None:
        """Per-scene full fine-tune of the compact restorer (steps/tune.py)."""
        from go_core.compact.restorer import load_restorer
        from go_core.compact.tuning import held_out_loss, tune_compact
        from go_core.io.safetensors_file import write_safetensors
        from go_core.repair.data import training_views
        from go_core.repair.pairs import LooPairs, pair_tensors, training_view_references, with_reference

        info = compact_info(inputs)
        model = load_restorer(info["name"])  # missing or corrupt weights: one MissingWeightsError
        base = {"repair_model": "compact", "compact": info}
        if not params.finetune:
            art.write_json(
                ctx.out_dir,
                art.TUNE_INFO,
                {
                    **base,
                    "status": "pretrained",
                    "reason": "ablation: no fine-tuning (pretrained restorer only)",
                },
            )
            ctx.record(status="pretrained", repair_model="compact", reason="ablation: no fine-tuning")
            return
        settings = compact_tune_settings(params)
        if settings.resolution % model.scale:
            raise ValueError(
                f"tune.compact_resolution must be a multiple of {model.scale}, got {settings.resolution}"
            )
        _, views = training_views(inputs["scene"], inputs.get("mask"), inputs["coarse"])
        choice = restorer_choice(ctx, inputs, params, info["name"], views)
        if choice is not None and choice["chosen"] != info["name"]:
            _write_prior_chosen(ctx, choice)
            return
        source = _pair_source(inputs, params, views)
        draw, loo = source.draw, LooPairs(inputs["loo"])
        held = [loo.get(i) for i in range(len(loo))]
        if model.channels == 8:  # a prior with a reference input: each pair gets its view's reference
            refs = training_view_references(views, source.coarse, params.backend)
            draw = lambda rng, gen: with_reference(source.draw(rng, gen), refs)  # noqa: E731
            held = [with_reference(p, refs) for p in held]
        loo_pairs = [pair_tensors(p, settings.resolution, model.channels) for p in held]
        before = held_out_loss(model, loo_pairs)
        bar = ResumedProgress(ctx, settings.steps, "compact tuning")
        summary = tune_compact(
            model, draw, source.schedule, settings, ctx.seed, Path(ctx.checkpoint_dir),
            on_step=lambda step, loss: bar.advance(step), fingerprint_extra=info["sha256"],
        )  # fmt: skip
        bar.close()
        after = held_out_loss(model, loo_pairs)
        resumed_from = summary.pop("resumed_from")
        tensors = model.tuned_tensors()
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
            **({"choice": choice} if choice is not None else {}),
        }
        art.write_json(ctx.out_dir, art.TUNE_INFO, out)
        log = summary["loss_log"]
        ctx.record(
            status="ok", repair_model="compact", steps=settings.steps, resumed_from=resumed_from,
            loss_first=log[0]["loss"] if log else None, loss_last=log[-1]["loss"] if log else None,
            loo_pairs_l1_before=round(before, 6), loo_pairs_l1_after=round(after, 6),
            pairs_used=summary["pairs_used"],
        )  # fmt: skip

    def load(
        self, inputs: dict[str, Path], tune_info: dict, params: RepairParams, device: str
    ) -> tuple[Any, str, RepairParams]:
        if params.loss == "sds":
            raise GoError("repair.loss 'sds' needs the sd15 repair model (weights.repair_model)")
        engine, note = self._engine(inputs, tune_info, params.use_lora, device)
        res = params.compact_resolution
        if res % engine.restorer.scale:
            raise GoError(
                f"repair.compact_resolution must be a multiple of {engine.restorer.scale}, got {res}"
            )
        return engine, note, params

    @staticmethod
    def _engine(inputs: dict[str, Path], tune_info: dict, use_lora: bool, device: str):
        """(CompactRepair, "fine-tuned" | "pretrained (no fine-tuning)") from the tune step's artifact."""
        tuned = use_lora and tune_info.get("status") == "ok"
        weights = Path(inputs["tune"]) / tune_info["tuned"] if tuned else None
        engine = compact_engine(tune_info["compact"]["name"], device, weights)
        return engine, "fine-tuned" if tuned else "pretrained (no fine-tuning)"


def restorer_choice(ctx, inputs: dict[str, Path], params: TuneParams, name: str, views) -> dict | None:
    """tune.json's ``choice`` between the run's restorer ``name`` tuned and ``params.prior_choice`` as
    shipped, on the held-out leave-one-out folds (go_core.compact.choice); None when there is nothing to
    choose (no prior named, or the run's restorer is a prior itself). Each fold's scores are kept in the
    checkpoint folder, so a resumed step does not tune that fold again."""
    from go_core.compact.choice import FoldScore, choice_record
    from go_core.compact.prior import SHIPPED
    from go_core.io.atomic import atomic_write_json

    if not params.prior_choice or name in SHIPPED:
        return None
    held = held_out_pairs(inputs)
    folder = Path(ctx.checkpoint_dir) / "restorer_choice"
    folds = [FoldScore(**json.loads(f.read_text(encoding="utf-8"))) for f in folder.glob("fold_*.json")]
    done = {f.view for f in folds}
    if len(done) < len(held):
        prior_outputs = _prior_outputs(inputs, params, views, held)
        for view in held:
            if view not in done:
                folds.append(
                    _fold_score(ctx, inputs, params, name, views, view, held[view], prior_outputs[view])
                )
                atomic_write_json(folder / f"fold_{view}.json", asdict(folds[-1]))
    folds.sort(key=lambda f: f.view)
    record = choice_record(folds, name, params.prior_choice)
    ctx.record(
        restorer_chosen=record["chosen"],
        consensus_restorer=record["consensus_restorer"],
        tuned_psnr=record["tuned_psnr"],
        prior_psnr=record["prior_psnr"],
        blend_psnr=record["blend_psnr"],
    )
    return record


def held_out_pairs(inputs: dict[str, Path]) -> dict[int, list]:
    """The leave-one-out pairs grouped by training view (each fold's held-out set), read once for every
    fold."""
    from go_core.repair.pairs import LooPairs

    loo = LooPairs(inputs["loo"])
    pairs = [loo.get(i) for i in range(len(loo))]
    return {view: [p for p in pairs if p.view == view] for view in sorted({p.view for p in pairs})}


def _prior_outputs(
    inputs: dict[str, Path], params: TuneParams, views, held: dict[int, list]
) -> dict[int, list]:
    """The prior as shipped, restoring each training view's leave-one-out pairs, with the reference input
    where the prior takes one (the nearest other training view, warped through the coarse model): computed
    once for every fold, as neither depends on the fold's tuning."""
    from go_core.compact.choice import restored
    from go_core.compact.restorer import load_restorer
    from go_core.repair.pairs import pair_tensors, training_view_references, with_reference

    resolution = compact_tune_settings(params).resolution
    prior = load_restorer(params.prior_choice)
    refs = None
    if prior.channels == 8:
        refs = training_view_references(views, art.read_gaussians(inputs["coarse"]).detach(), params.backend)
    out = {}
    for view, pairs in held.items():
        pairs = [with_reference(p, refs) for p in pairs] if refs is not None else pairs
        out[view] = restored(prior, [pair_tensors(p, resolution, prior.channels) for p in pairs])
    return out


def _fold_score(
    ctx, inputs: dict[str, Path], params: TuneParams, name: str, views, view: int, held: list, prior: list
):
    """One fold: ``name`` tuned as the tune step tunes it on every pair not of ``view`` (at a seed of its
    own), and the mean PSNR on ``held`` (``view``'s leave-one-out pairs) of its output, of the prior's
    (``prior``, the same pairs restored) and of their mean (go_core.compact.choice.FoldScore)."""
    from go_core.compact.choice import FoldScore, blend_psnr, mean_psnr, restored
    from go_core.compact.restorer import load_restorer
    from go_core.compact.tuning import tune_compact
    from go_core.repair.pairs import pair_tensors
    from go_core.seeding import derive_seed

    settings = fold_tune_settings(params)
    source = _pair_source(inputs, params, views)

    def draw(rng, gen):
        while True:
            pair = source.draw(rng, gen)
            if pair.view != view:
                return pair

    model = load_restorer(name)
    tune_compact(model, draw, source.schedule, settings, derive_seed(ctx.seed, "restorer_choice", view))
    pairs = [pair_tensors(p, settings.resolution, model.channels) for p in held]
    tuned = restored(model, pairs)
    return FoldScore(
        view, len(held), mean_psnr(tuned, pairs), mean_psnr(prior, pairs), blend_psnr(tuned, prior, pairs)
    )


def _write_prior_chosen(ctx, choice: dict) -> None:
    """tune.json when the prior won the held-out folds: the prior as shipped repairs (status pretrained)."""
    reason = "the repair prior as shipped restored the held-out leave-one-out views better than the tuned one"
    art.write_json(
        ctx.out_dir,
        art.TUNE_INFO,
        {
            "repair_model": "compact",
            "compact": compact_model_info(choice["prior"]),
            "status": "pretrained",
            "reason": reason,
            "choice": choice,
        },
    )
    ctx.record(status="pretrained", repair_model="compact", reason=reason)


def compact_engine(name: str, device: str, tuned: Path | None = None):
    """The one-pass repair engine (go_core.compact.engine.CompactRepair) of the compact model ``name``: as
    shipped, or with the tune step's fine-tuned weights ``tuned`` (a safetensors file). Missing or corrupt
    weights: one clear error."""
    from go_core.compact.engine import CompactRepair
    from go_core.compact.restorer import load_restorer

    restorer = load_restorer(name)
    if tuned is not None:
        from safetensors.torch import load_file

        restorer.load_tuned(load_file(str(tuned)))
    return CompactRepair(restorer, device)


class SD15Model:
    """SD1.5 + ControlNet-tile + CLIP, tuned with LoRA (paper Sec. 3.4) and repairing by SDEdit."""

    name = "sd15"

    def tune(self, ctx, inputs: dict[str, Path], params: TuneParams) -> None:
        from go_core.diffusion.lora import LoraSpec, add_lora, save_lora
        from go_core.diffusion.models import load_repair_models, precision_dtypes
        from go_core.diffusion.sampler import RepairDiffusion
        from go_core.repair.data import training_views
        from go_core.repair.tuning import TuneSettings, tune

        paths = weight_paths(inputs)
        weights = paths.describe()
        prompt = params.sd15_prompt
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
        weight_dtype, autocast_dtype = precision_dtypes(device, params.sd15_precision)
        models = load_repair_models(paths, device=device, dtype=weight_dtype)  # unreadable files raise
        spec = LoraSpec(
            rank=params.sd15_rank,
            alpha=params.sd15_alpha,
            unet=params.sd15_unet,
            controlnet=params.sd15_controlnet,
            text_encoder=params.sd15_text_encoder,
        )
        counts = add_lora(models, spec, seed=int(ctx.seed))
        diffusion = RepairDiffusion(models, prompt=prompt, device=device, autocast_dtype=autocast_dtype)

        _, views = training_views(inputs["scene"], inputs.get("mask"), inputs["coarse"])
        source = _pair_source(inputs, params, views)
        settings = TuneSettings(
            steps=params.sd15_steps,
            lr=params.sd15_lr,
            betas=params.betas,
            weight_decay=params.sd15_weight_decay,
            resolution=params.sd15_resolution,
            checkpoint_every=params.checkpoint_every,
        )
        bar = ResumedProgress(ctx, settings.steps, "LoRA tuning")
        summary = tune(
            diffusion,
            spec,
            source,
            settings,
            ctx.seed,
            checkpoint_dir=Path(ctx.checkpoint_dir),
            on_step=lambda step, loss: bar.advance(step, loss=loss),
            fingerprint_extra=device,
        )
        bar.close()
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

    def load(
        self, inputs: dict[str, Path], tune_info: dict, params: RepairParams, device: str
    ) -> tuple[Any, str, RepairParams]:
        from go_core.diffusion.lora import add_lora, load_lora_state_dict, read_lora
        from go_core.diffusion.models import WeightPaths, load_repair_models, precision_dtypes
        from go_core.diffusion.sampler import RepairDiffusion

        paths = WeightPaths(**tune_info["weights"])
        weight_dtype, autocast_dtype = precision_dtypes(device, params.sd15_precision)
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
            guidance_scale=params.sd15_guidance_scale,
        )
        return diffusion, "fine-tuned" if use_lora else "pretrained (no fine-tuning)", params


MODELS: dict[str, RepairModel] = {"compact": CompactModel(), "sd15": SD15Model()}


def repair_model_named(name: str) -> RepairModel:
    """The implementation of the repair model ``name`` (weights.json / tune.json ``repair_model``)."""
    return MODELS[name]
