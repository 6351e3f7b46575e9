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
from go_core.coarse.depth_prior import load_depth_priors
from go_core.coarse.loop import TrainView, optimize
from go_core.io.checkpoint import CheckpointSpec
from go_core.io.curves import write_curves
from go_core.poses.refine import apply_corrections
from go_core.seeding import torch_generator

if TYPE_CHECKING:
    from go_pipeline.steps.params import CoarseParams


def _poses_summary(aligned: bool, refined: bool) -> str:
    """``coarse.json`` "poses": "as given", "refined", "aligned, not refined" or "aligned, refined"."""
    if not aligned:
        return "refined" if refined else "as given"
    return "aligned, refined" if refined else "aligned, not refined"


def run(ctx, inputs: dict[str, Path], params: CoarseParams) -> None:
    t0 = time.process_time()
    scene = art.read_scene(inputs["scene"])
    masks = art.read_masks(inputs["mask"], len(scene.train))
    init = art.read_gaussians(inputs["hull"])
    depths = load_depth_priors(inputs["depth"]) if "depth" in inputs else None
    if depths is not None and len(depths) != len(scene.train):
        depths = None
    aligned = art.cameras_aligned(inputs["hull"])  # hull.align_poses: start from the hull's cameras
    cameras = art.read_fitted_cameras(inputs["hull"], scene.train_cameras)
    views = [
        TrainView.from_arrays(c, v.image, m, depths[i] if depths is not None else None)
        for i, (v, c, m) in enumerate(zip(scene.train, cameras, masks, strict=True))
    ]
    generator = torch_generator(int(ctx.seed))  # the run's seed itself (derive_seed without tags)
    state: dict = {"bar": None}

    def progress(step: int, info: dict) -> None:
        if state["bar"] is None:
            state["bar"] = ctx.progress(params.iterations, "coarse 3DGS", completed=step - 1)
        state["bar"].advance(1, loss=info["loss"], gaussians=info["n"])

    config = params.scaled_schedule()  # the schedules at the budget coarse.iterations
    spec = CheckpointSpec(Path(ctx.checkpoint_dir), every=params.checkpoint_every)
    gaussians, stats = optimize(
        init, views, config, generator=generator, on_progress=progress, checkpoint=spec
    )
    if state["bar"] is not None:
        state["bar"].close()
    stats.check_not_collapsed()  # nothing half-written: the step fails before its artifact
    art.write_gaussians(ctx.out_dir, gaussians)
    write_curves(art.CURVES.path(ctx.out_dir), stats.loss_log)  # loss, train PSNR, Gaussians per logged step
    cameras = [v.camera for v in views]
    if stats.pose_corrections is not None:  # coarse.refine_poses: the cameras the Gaussians were fitted with
        cameras = apply_corrections(cameras, stats.pose_corrections)
    art.write_cameras(ctx.out_dir, cameras, stats.pose_corrections, aligned=aligned)
    cpu_s = time.process_time() - t0
    info = {
        "gaussians": stats.final_count,
        "initial_gaussians": stats.initial_count,
        "max_gaussians_seen": stats.max_count,
        "floaters_removed": stats.floaters_removed,
        "densify": stats.densify,
        "depth_loss": "on" if stats.depth_loss_used else "off (no depth prior)" if depths is None else "off",
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
