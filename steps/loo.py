"""loo: leave-one-out runs → degraded/clean image pairs and the 3D-noise statistics (paper Sec. 3.4).

For each of the N training views: coarse training (the coarse step's own configuration, from coarse.json)
on the other N−1 views from the hull (phase 1), then
continued with all N views on a fixed set (phase 2); renders of the left-out view during phase 2 are the
degraded images, the left-out photo (on white) the clean one. Statistics: per-attribute, per-channel mean
and std of (phase-2 − phase-1) parameter differences, pooled over the runs.

Runs are independent: ``workers`` > 1 runs them in parallel processes (default 1: sequential, the 2-core
case). Each finished run is kept in ``ctx.checkpoint_dir`` so a killed step resumes where it was.

Outputs: ``loo.json`` (runs, statistics, pair index), ``loo_pairs.npz`` (``degraded_<k>_<j>``,
``clean_<k>``, ``mask_<k>`` uint8 arrays).
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
from go_pipeline.steps._common import repair_weights_missing, write_skipped

from go_core.errors import SceneError
from go_core.gaussians import Gaussians
from go_core.io.atomic import atomic_write_json
from go_core.repair.loo import LooSettings, load_run, run_job, run_one
from go_core.repair.noise import difference_stats

SKIP_IF_SKIPPED = ("weights",)  # the runner skips this step, without a worker, when that input skipped


def settings_from(params: dict, sh_degree: int, coarse_config: dict | None = None) -> LooSettings:
    return LooSettings(
        coarse_config=coarse_config,
        phase1_iterations=int(params.get("phase1_iterations", 6000)),
        phase2_iterations=int(params.get("phase2_iterations", 4000)),
        renders=int(params.get("renders", 10)),
        compress_schedule=bool(params.get("compress_schedule", False)),
        checkpoint_every=int(params.get("checkpoint_every", 500)),
        sh_degree=sh_degree,
        backend=str(params.get("backend", "auto")),
    )


def run(ctx, inputs: dict[str, Path], params: dict) -> None:
    from go_core.io.npz import write_npz_deterministic
    from go_core.repair.data import training_views
    from go_core.training import scene_extent

    missing = repair_weights_missing(inputs)
    if missing:  # no repair model: the pairs would never be used, so don't pay for N coarse runs
        write_skipped(ctx, "loo.json", "repair model weights missing (see the weights step)")
        write_npz_deterministic(Path(ctx.out_dir) / "loo_pairs.npz", {})
        return
    scene, views = training_views(inputs["scene"], inputs.get("mask"))
    if len(views) < 2:
        raise SceneError(f"leave-one-out needs at least 2 training views, got {len(views)}", inputs["scene"])
    init = Gaussians.load(Path(inputs["hull"]) / "gaussians.npz")
    coarse = Gaussians.load(Path(inputs["coarse"]) / "gaussians.npz")
    coarse_json = Path(inputs["coarse"]) / "coarse.json"
    coarse_config = json.loads(coarse_json.read_text()).get("config") if coarse_json.is_file() else None
    settings = settings_from(params, coarse.sh_degree, coarse_config)
    extent = scene_extent([v.camera for v in views])
    workers = max(1, int(params.get("workers", 1)))
    run_dirs = [Path(ctx.checkpoint_dir) / f"run_{k:02d}" for k in range(len(views))]
    pending = [k for k, d in enumerate(run_dirs) if not (d / "done.json").is_file()]
    ctx.log.info("leave-one-out: %d runs (%d to do), %d worker(s)", len(views), len(pending), workers)
    progress = ctx.progress(len(views), "leave-one-out runs", completed=len(views) - len(pending))
    if workers > 1 and len(pending) > 1:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor, as_completed

        jobs = [
            {
                "index": k,
                "views": views,
                "init": init,
                "settings": asdict(settings),
                "seed": ctx.seed,
                "run_dir": str(run_dirs[k]),
                "extent": extent,
                "threads": 1,
            }
            for k in pending
        ]
        with ProcessPoolExecutor(
            max_workers=min(workers, len(jobs)), mp_context=mp.get_context("spawn")
        ) as ex:
            for fut in as_completed([ex.submit(run_job, j) for j in jobs]):
                fut.result()
                progress.advance()
    else:
        total = settings.phase1_iterations + settings.phase2_iterations
        for k in pending:
            inner: dict = {}

            def tick(step: int, info: dict, k: int = k, inner: dict = inner) -> None:
                if "bar" not in inner:  # created at the first step run: a resumed run starts where it was
                    what = f"run {k + 1}/{len(views)} (without {views[k].camera.name})"
                    inner["bar"] = ctx.progress(total, what, completed=step - 1)
                inner["bar"].advance(1, loss=info["loss"], gaussians=info["n"])

            run_one(k, views, init, settings, ctx.seed, run_dirs[k], extent, on_progress=tick)
            if "bar" in inner:
                inner["bar"].close()
            progress.advance()
    progress.close()

    runs = [load_run(d) for d in run_dirs]
    stats = difference_stats([(r.before, r.after) for r in runs])
    arrays: dict[str, np.ndarray] = {}
    pairs = []
    for r in runs:
        arrays[f"clean_{r.index}"] = np.load(run_dirs[r.index] / "clean.npy")
        arrays[f"mask_{r.index}"] = np.load(run_dirs[r.index] / "mask.npy")
        for j, (step, img) in enumerate(zip(r.render_steps, r.renders, strict=True)):
            key = f"degraded_{r.index}_{j}"
            arrays[key] = img
            pairs.append(
                {
                    "view": r.index,
                    "name": r.name,
                    "phase2_step": step,
                    "degraded": key,
                    "clean": f"clean_{r.index}",
                    "mask": f"mask_{r.index}",
                }
            )
    write_npz_deterministic(Path(ctx.out_dir) / "loo_pairs.npz", arrays)
    summary = {
        "status": "ok",
        "settings": asdict(settings),
        "runs": [
            {
                "view": r.index,
                "name": r.name,
                "count_phase1": len(r.before),
                "render_steps": r.render_steps,
                "phase2_final_loss": r.info.get("phase2_final_loss"),
            }
            for r in runs
        ],
        "stats": stats.to_json(),
        "pairs": pairs,
    }
    atomic_write_json(Path(ctx.out_dir) / "loo.json", summary)
    ctx.record(
        workers=workers,
        runs=len(runs),
        pairs=len(pairs),
        gaussians_compared=stats.count,
        position_std=[round(s, 6) for s in stats.std["means"]],
    )
