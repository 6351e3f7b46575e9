"""coarse: 3DGS optimisation from the hull Gaussians with the paper's structure priors (Sec. 3.3).

Loss 0.8·L1 + 0.2·D-SSIM on random backgrounds + λm·BCE(alpha, mask) + λd·depth (when the depth step
produced a prior); 3DGS densification (strategy object with a Gaussian budget and pruning of Gaussians that
contribute nothing) and floater elimination. All settings are step params (pipeline.yaml ``coarse:``); see
docs/coarse.md for the ablation spellings. Checkpoints go to ``ctx.checkpoint_dir``; a killed run resumes
and produces a bit-identical ``gaussians.npz``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

from go_core import artifacts as art
from go_core.coarse.fit import coarse_inputs, fit_coarse
from go_core.io.checkpoint import CheckpointSpec
from go_core.io.curves import write_curves

if TYPE_CHECKING:
    from go_pipeline.steps.params import CoarseParams


def _poses_summary(aligned: bool, refined: bool) -> str:
    """``coarse.json`` "poses": "as given", "refined", "aligned, not refined" or "aligned, refined"."""
    if not aligned:
        return "refined" if refined else "as given"
    return "aligned, refined" if refined else "aligned, not refined"


def _depth_loss_summary(used: bool, given: bool) -> str:
    """``coarse.json`` "depth_loss": "on", "off", or "off (no depth prior)" when the depth step made none."""
    return "on" if used else "off" if given else "off (no depth prior)"


def run(ctx, inputs: dict[str, Path], params: CoarseParams) -> None:
    t0 = time.process_time()
    fit_inputs = coarse_inputs(inputs["scene"], inputs["mask"], inputs["hull"], inputs.get("depth"))
    state: dict = {"bar": None}

    def progress(step: int, info: dict) -> None:
        if state["bar"] is None:
            state["bar"] = ctx.progress(params.iterations, "coarse 3DGS", completed=step - 1)
        state["bar"].advance(1, loss=info["loss"], gaussians=info["n"])

    config = params.scaled_schedule()  # the schedules at the budget coarse.iterations
    spec = CheckpointSpec(Path(ctx.checkpoint_dir), every=params.checkpoint_every)
    # the run's seed itself (derive_seed without tags); nothing half-written: a collapse fails before writing
    gaussians, stats, cameras = fit_coarse(fit_inputs, config, int(ctx.seed), spec, progress)
    if state["bar"] is not None:
        state["bar"].close()
    art.write_gaussians(ctx.out_dir, gaussians)
    write_curves(art.CURVES.path(ctx.out_dir), stats.loss_log)  # loss, train PSNR, Gaussians per logged step
    aligned = fit_inputs.aligned  # hull.align_poses: started from the hull's cameras
    art.write_cameras(ctx.out_dir, cameras, stats.pose_corrections, aligned=aligned)
    cpu_s = time.process_time() - t0
    info = {
        "gaussians": stats.final_count,
        "initial_gaussians": stats.initial_count,
        "max_gaussians_seen": stats.max_count,
        "floaters_removed": stats.floaters_removed,
        "densify": stats.densify,
        "depth_loss": _depth_loss_summary(stats.depth_loss_used, fit_inputs.depth_given),
        "iterations": stats.iterations,
        "poses": _poses_summary(aligned, refined=stats.pose_corrections is not None),
    }
    # coarse.json stays byte-identical between a resumed and an uninterrupted run: timing goes to the record
    art.write_json(
        ctx.out_dir,
        art.COARSE_INFO,
        {
            **info,
            "config": config.to_dict(),
            "floater_passes": stats.floater_passes,
            "color_transforms": stats.color_transforms,  # coarse.color_correction: per view [A, b]; else None
            "loss_log": stats.loss_log,
        },
    )
    ctx.record(**info, resumed_from=stats.resumed_from, cpu_s_this_process=round(cpu_s, 2))
