"""loo: leave-one-out runs → degraded/clean image pairs and the 3D-noise statistics (paper Sec. 3.4).

For each of the N training views: coarse training (the coarse step's settings, given by the runner)
on the other N−1 views from the hull (phase 1), then
continued with all N views on a fixed set (phase 2); renders of the left-out view during phase 2 are the
degraded images, the left-out photo (on white) the clean one. Statistics: per-attribute, per-channel mean
and std of (phase-2 − phase-1) parameter differences, pooled over the runs.

Runs are independent: on a CPU they run in parallel processes, one per thread of the step (``workers`` 0,
``loo_workers``), each on its share of the threads: on 2 cores 1.22x faster than one process on 2 threads
(photos/ethiopian_head at 256 px: 238 vs 290 s), with bit-identical artifacts (the rasterizer's sums do
not depend on the thread count). Each finished run is kept in ``ctx.checkpoint_dir`` so a killed step
resumes where it was.

Outputs: ``loo.json`` (runs, statistics, pair index), ``loo_pairs.npz`` (uint8 arrays
``degraded_<k>_<j>``: the render on white and its alpha, RGBA; ``clean_<k>``; ``mask_<k>``).
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from go_core import artifacts as art
from go_core.errors import SceneError
from go_core.repair.loo import downscaled, load_clean_and_mask, load_run, run_is_done, run_job, run_one
from go_core.repair.noise import difference_stats

if TYPE_CHECKING:
    from go_pipeline.steps.params import LooParams


def loo_workers(requested: int, runs: int, device: str, threads: int) -> tuple[int, int]:
    """(processes, threads each) for ``runs`` leave-one-out runs: ``requested`` processes, or with 0 one
    per thread on a CPU (at most one per run) and one on CUDA; the threads are shared out evenly."""
    if requested > 0:
        workers = requested
    elif device.startswith("cuda"):
        workers = 1
    else:
        workers = max(1, min(runs, threads))
    return workers, max(1, threads // workers)


def run(ctx, inputs: dict[str, Path], params: LooParams) -> None:
    import torch

    from go_core.coarse.loop import scene_extent
    from go_core.io.npz import write_npz_deterministic
    from go_core.repair.data import training_views

    scene, views = training_views(inputs["scene"], inputs.get("mask"), inputs["coarse"])  # coarse's cameras
    if len(views) < 2:
        raise SceneError(f"leave-one-out needs at least 2 training views, got {len(views)}", inputs["scene"])
    init = art.read_gaussians(inputs["hull"])
    settings = params  # LooSettings with the coarse step's settings (params.coarse)
    extent = scene_extent([v.camera for v in views])
    trained = downscaled(views, params.train_size)  # renders and clean photos stay at full size
    workers, threads = loo_workers(params.workers, len(views), str(ctx.device), torch.get_num_threads())
    run_dirs = [Path(ctx.checkpoint_dir) / f"run_{k:02d}" for k in range(len(views))]
    pending = [k for k, d in enumerate(run_dirs) if not run_is_done(d)]
    ctx.log.info("leave-one-out: %d runs (%d to do), %d worker(s)", len(views), len(pending), workers)
    progress = ctx.progress(len(views), "leave-one-out runs", completed=len(views) - len(pending))
    job = {"views": trained, "init": init, "settings": settings, "seed": ctx.seed, "extent": extent}
    if workers > 1 and len(pending) > 1:
        _run_in_processes(pending, views, run_dirs, job, min(workers, len(pending)), threads, progress)
    else:
        _run_here(ctx, pending, views, run_dirs, job, progress)
    progress.close()

    runs = [load_run(d) for d in run_dirs]
    stats = difference_stats([(r.before, r.after) for r in runs])
    arrays, pairs = _pairs(runs, run_dirs)
    write_npz_deterministic(art.LOO_PAIRS.path(ctx.out_dir), arrays)
    summary = {
        "status": "ok",
        "settings": {k: v for k, v in asdict(settings).items() if k != "workers"},  # workers: same result
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
    art.write_json(ctx.out_dir, art.LOO_INFO, summary)
    ctx.record(
        workers=workers,
        runs=len(runs),
        pairs=len(pairs),
        gaussians_compared=stats.count,
        position_std=[round(s, 6) for s in stats.std["means"]],
    )


def _run_in_processes(pending, views, run_dirs, job: dict, workers: int, threads: int, progress) -> None:
    """The pending leave-one-out runs in ``workers`` spawned processes of ``threads`` threads each."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    jobs = [
        {**job, "index": k, "shown": views[k], "run_dir": str(run_dirs[k]), "threads": threads}
        for k in pending
    ]
    with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as ex:
        for fut in as_completed([ex.submit(run_job, j) for j in jobs]):
            fut.result()
            progress.advance()


def _run_here(ctx, pending, views, run_dirs, job: dict, progress) -> None:
    """The pending leave-one-out runs one after the other in this process, each with its own bar."""
    settings = job["settings"]
    total = settings.phase1_iterations + settings.phase2_iterations
    for k in pending:
        inner: dict = {}

        def tick(step: int, info: dict, k: int = k, inner: dict = inner) -> None:
            if "bar" not in inner:  # created at the first step run: a resumed run starts where it was
                what = f"run {k + 1}/{len(views)} (without {views[k].camera.name})"
                inner["bar"] = ctx.progress(total, what, completed=step - 1)
            inner["bar"].advance(1, loss=info["loss"], gaussians=info["n"])

        run_one(
            k,
            job["views"],
            job["init"],
            settings,
            job["seed"],
            run_dirs[k],
            job["extent"],
            on_progress=tick,
            shown=views[k],
        )
        if "bar" in inner:
            inner["bar"].close()
        progress.advance()


def _pairs(runs, run_dirs) -> tuple[dict[str, np.ndarray], list[dict]]:
    """The arrays of loo_pairs.npz (each run's clean photo, mask and degraded renders) and the pairs'
    records naming them."""
    arrays: dict[str, np.ndarray] = {}
    pairs = []
    for r in runs:
        arrays[f"clean_{r.index}"], arrays[f"mask_{r.index}"] = load_clean_and_mask(run_dirs[r.index])
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
    return arrays, pairs
