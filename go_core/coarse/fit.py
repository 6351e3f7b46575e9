"""The coarse stage from its upstream artifacts: the training views it fits (scene, masks, the hull's
cameras, depth priors) and one fit of the hull Gaussians to them. The coarse step runs it once; the repair
step runs it again with a derived seed for the second model of its consensus (go_core.repair.second_model).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from go_core import artifacts as art
from go_core.camera import Camera
from go_core.coarse.depth_prior import load_depth_priors
from go_core.coarse.loop import TrainStats, TrainView, optimize
from go_core.coarse.settings import CoarseConfig
from go_core.gaussians import Gaussians
from go_core.io.checkpoint import CheckpointSpec
from go_core.poses.refine import apply_corrections
from go_core.seeding import torch_generator


@dataclass(frozen=True)
class CoarseInputs:
    """What the coarse stage fits: the hull Gaussians, the training views (with the hull's cameras, aligned
    when hull.align_poses moved them) and whether they were aligned."""

    init: Gaussians
    views: list[TrainView]
    aligned: bool

    @property
    def depth_given(self) -> bool:
        """Whether the views carry the depth step's priors (one per training view, else none)."""
        return any(v.depth is not None for v in self.views)


def coarse_inputs(
    scene_dir: str | Path, mask_dir: str | Path, hull_dir: str | Path, depth_dir: str | Path | None = None
) -> CoarseInputs:
    """The coarse stage's inputs from the scene, mask, hull and (optional) depth step artifacts."""
    scene = art.read_scene(scene_dir)
    masks = art.read_masks(mask_dir, len(scene.train))
    depths = load_depth_priors(depth_dir) if depth_dir is not None else None
    if depths is not None and len(depths) != len(scene.train):
        depths = None
    cameras = art.read_fitted_cameras(hull_dir, scene.train_cameras)
    views = [
        TrainView.from_arrays(c, v.image, m, depths[i] if depths is not None else None)
        for i, (v, c, m) in enumerate(zip(scene.train, cameras, masks, strict=True))
    ]
    return CoarseInputs(art.read_gaussians(hull_dir), views, art.cameras_aligned(hull_dir))


def fit_coarse(
    inputs: CoarseInputs,
    config: CoarseConfig,
    seed: int,
    checkpoint: CheckpointSpec | None = None,
    on_progress: Callable[[int, dict], None] | None = None,
) -> tuple[Gaussians, TrainStats, list[Camera]]:
    """(Gaussians, stats, the cameras they were fitted with) of one coarse fit at ``seed``; a
    CollapsedModelError, before anything is written, when pruning emptied the model."""
    gaussians, stats = optimize(
        inputs.init,
        inputs.views,
        config,
        generator=torch_generator(int(seed)),
        on_progress=on_progress,
        checkpoint=checkpoint,
    )
    stats.check_not_collapsed()
    cameras = [v.camera for v in inputs.views]
    if stats.pose_corrections is not None:  # coarse.refine_poses: the cameras the Gaussians were fitted with
        cameras = apply_corrections(cameras, stats.pose_corrections)
    return gaussians, stats, cameras


__all__ = ["CoarseInputs", "coarse_inputs", "fit_coarse"]
