"""Settings of the 3DGS optimisation loop (go_core.coarse.loop), one flat dataclass as gsplat's strategies
are.

``CoarseConfig`` is the learning rates, the densification and the floater settings plus the loss weights and
schedule, each under the one name users know from pipeline.yaml (``coarse.densify_from``,
``coarse.min_opacity``, ...). The parts are dataclasses of their own so a component takes only what it
needs (``DensifyStrategy(DensifyConfig)``, ``GaussianOptimizer(LearningRates)``); a ``CoarseConfig`` is each
of them. Torch-free, so the runner checks settings without importing torch.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Literal

from go_core.config import SettingError, setting

SCHEDULES = {"code": (1.0, 2.33), "paper": (1.0, 0.0)}
Backend = Literal["auto", "cpu", "cuda", "reference"]


@dataclass
class LearningRates:
    """3DGS learning rates; the position rate is multiplied by the scene extent and decays exponentially."""

    position_lr_init: float = setting(0.00016, gt=0, doc="x scene extent (3DGS)")
    position_lr_final: float = setting(0.0000016, gt=0)
    position_lr_max_steps: int = setting(30000, ge=1)
    feature_lr: float = setting(0.0025, ge=0, doc="SH DC; the SH rest learns at feature_lr / 20")
    opacity_lr: float = setting(0.05, ge=0)
    scaling_lr: float = setting(0.005, ge=0)
    rotation_lr: float = setting(0.001, ge=0)

    @property
    def feature_rest_lr(self) -> float:
        return self.feature_lr / 20.0

    def position_lr_at(self, step: int, extent: float) -> float:
        """Log-linear decay from init to final over ``position_lr_max_steps`` (3DGS's schedule, no delay)."""
        t = min(max(step / max(self.position_lr_max_steps, 1), 0.0), 1.0)
        log_lr = math.log(self.position_lr_init) * (1 - t) + math.log(self.position_lr_final) * t
        return math.exp(log_lr) * extent


@dataclass
class DensifyConfig:
    """3DGS adaptive density control, with a Gaussian budget and pruning of non-contributing Gaussians."""

    densify_from: int = setting(500, ge=0, doc="first densification after this step")
    densify_until: int = setting(6000, ge=0, doc="none at or after this step")
    densify_every: int = setting(100, ge=1)
    densify_grad_threshold: float = setting(0.0002, ge=0, doc="screen-space gradient in NDC units (tau_pos)")
    percent_dense: float = setting(0.01, ge=0, doc="clone if max scale <= percent_dense x extent, else split")
    split_count: int = setting(2, ge=2, doc="a split Gaussian becomes this many")
    min_opacity: float = setting(0.005, ge=0, lt=1, doc="prune below this opacity")
    opacity_reset_every: int = setting(1000, ge=0, doc="0: never; only while densifying")
    opacity_reset_value: float = setting(0.01, gt=0, lt=1, doc="opacities are clamped to this at a reset")
    max_screen_size: float = setting(20.0, ge=0, doc="px; prune larger after the 1st reset (0: off)")
    max_screen_fraction: float = setting(
        0.15, ge=0, doc="x the object's silhouette size (sqrt of mask area) replaces max_screen_size; 0: px"
    )
    max_world_size: float = setting(0.1, ge=0, doc="x extent; prune larger after the first reset (0: off)")
    max_gaussians: int = setting(150000, ge=0, doc="Gaussian budget (0: unlimited)")
    prune_no_contribution: bool = setting(True, doc="prune Gaussians with no colour gradient")


@dataclass
class FloaterConfig:
    """Floater elimination (go_core.coarse.floaters): every floater_every steps, from floater_from to
    floater_until."""

    floaters: bool = setting(True, doc="floater elimination (ablation: false)")
    floater_every: int = setting(500, ge=0)
    floater_from: int = setting(500, ge=0, doc="the schedule's start (lambda = its first value here)")
    floater_until: int = setting(6000, ge=0, doc="last step at which it runs (lambda = its last value here)")
    floater_schedule: Literal["code", "paper"] = setting("code", doc="code (1 -> 2.33) | paper (1 -> 0)")
    floater_max_remove_fraction: float = setting(0.5, gt=0, le=1, doc="never remove more in one pass")

    def __post_init__(self) -> None:
        if self.floater_schedule not in SCHEDULES:
            problem = f"must be one of {sorted(SCHEDULES)}, got {self.floater_schedule!r}"
            raise SettingError("floater_schedule", problem)

    def floater_due(self, step: int) -> bool:
        return (
            self.floaters
            and self.floater_every > 0
            and step % self.floater_every == 0
            and self.floater_from <= step <= self.floater_until
        )

    def floater_lambda_at(self, step: int) -> float:
        lo, hi = SCHEDULES[self.floater_schedule]
        span = max(self.floater_until - self.floater_from, 1)
        t = min(max((step - self.floater_from) / span, 0.0), 1.0)
        return lo + (hi - lo) * t


@dataclass
class RegularizerConfig:
    """Weights of the sparse-view regularisers (go_core.coarse.regularizers; 0 = off: the loop is then
    bit-identical to plain 3DGS)."""

    drop_gamma: float = setting(0.2, ge=0, lt=1, doc="DropGaussian: final drop rate (rate gamma t/T)")
    lambda_outside: float = setting(0.0, ge=0, doc="alpha^2 outside the training masks; 0: off")
    lambda_anisotropy: float = setting(
        0.01,
        ge=0,
        doc="hinge on max/min scale ratio above max_anisotropy; 0: off (on since it measured better on real "
        "captures, docs/real_captures.md)",
    )
    max_anisotropy: float = setting(10.0, ge=1)
    lambda_opacity: float = setting(0.01, ge=0, doc="opacity decay: mean opacity; 0: off")
    lambda_inside: float = setting(0.0, ge=0, doc="(1 - alpha)^2 inside the eroded training masks; 0: off")
    inside_erode_px: int = setting(2, ge=0, doc="lambda_inside: mask erosion (px) kept off the binary edge")
    lambda_opacity_entropy: float = setting(0.0, ge=0, doc="binary entropy of the opacities (0 or 1); 0: off")
    lambda_flatten: float = setting(0.0, ge=0, doc="mean smallest Gaussian scale / extent (discs); 0: off")
    lambda_depth_normal: float = setting(
        0.0, ge=0, doc="1 - rendered normal . depth normal in the eroded mask (2DGS); 0: off; 1 more render"
    )
    depth_normal_from: int = setting(3000, ge=0, doc="lambda_depth_normal: first step (scaled schedule)")
    color_correction: bool = setting(False, doc="learn an affine colour transform per training view")
    color_lr: float = setting(0.001, ge=0, doc="color_correction: Adam lr of the transforms")


@dataclass
class PoseRefineConfig:
    """Joint pose refinement (go_core.poses.refine.JointPoses): a rotation + translation correction per
    training view optimised with the Gaussians through the rasterizer's viewmat gradients. The first
    training view is the gauge (kept as given). Off by default (after ``hull.align_poses`` it lowered
    test PSNR on the dev scenes, docs/coarse.md)."""

    refine_poses: bool = setting(False, doc="optimise a pose correction per training view (first view fixed)")
    pose_lr_rotation: float = setting(0.003, gt=0, doc="Adam lr of the rotations (rad), cosine-decayed x0.1")
    pose_lr_translation: float = setting(0.003, gt=0, doc="Adam lr of the shifts, x the mean camera distance")
    pose_refine_from: int = setting(500, ge=0, doc="first step with pose updates (the Gaussians form first)")


# The budget knob: step-based schedules are written for ``schedule_iterations`` (the paper's 10 000) and
# scaled by iterations / schedule_iterations (CoarseConfig.scaled_schedule): ``iterations`` sets the budget.
SCHEDULE_PARAMS: tuple[str, ...] = (
    "sh_increase_every",
    "position_lr_max_steps",
    "densify_from",
    "densify_until",
    "densify_every",
    "opacity_reset_every",
    "floater_every",
    "floater_from",
    "floater_until",
    "pose_refine_from",
    "depth_normal_from",
)


@dataclass
class CoarseConfig(PoseRefineConfig, RegularizerConfig, FloaterConfig, DensifyConfig, LearningRates):
    """Coarse 3DGS settings: the paper's / the authors' code's, except the budget (2500 scaled iterations)
    and the two regularisers measured better (DropGaussian, opacity decay; docs/coarse.md). The paper's:
    ``--profile paper``."""

    iterations: int = setting(2500, ge=0, doc="the budget (paper: 10000; schedules scale with it)")
    schedule_iterations: int = setting(10000, ge=0, doc="the length schedules are written for")
    opacity_reset_min_interval: int = setting(200, ge=0, doc="shorter scaled reset period: none")
    sh_degree: int = setting(2, ge=0, le=3, doc="raised by one every sh_increase_every iterations")
    sh_increase_every: int = setting(1000, ge=1)
    lambda_dssim: float = setting(0.2, ge=0, le=1)
    lambda_mask: float = setting(0.01, ge=0, doc="BCE(alpha, mask) (authors' code lambda_silhouette)")
    lambda_depth: float = setting(0.0005, ge=0, doc="used only with a depth prior (0: off)")
    depth_min_pixels: int = setting(10, ge=1, doc="skip the depth term when fewer valid pixels")
    random_background: bool = True
    background: tuple[float, float, float] = setting((1.0, 1.0, 1.0), ge=0, le=1, doc="when not random")
    backend: Backend = "auto"
    log_every: int = setting(100, ge=1, doc="loss log period")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["background"] = list(self.background)
        return d

    @staticmethod
    def from_dict(d: dict) -> CoarseConfig:
        from go_core.config import from_mapping

        return from_mapping(CoarseConfig, d)

    def scaled_schedule(self) -> CoarseConfig:
        """This config with every step-based schedule (``SCHEDULE_PARAMS``) scaled by
        ``iterations / schedule_iterations`` (rounded, positive ones at least 1); itself when
        ``schedule_iterations`` is 0 or equals ``iterations``.

        Opacity resets whose scaled period falls below ``opacity_reset_min_interval`` are switched off:
        recovering from a reset takes a fixed number of Adam steps (~100+), not a share of the run, so a short
        run would end right after one."""
        if self.schedule_iterations <= 0 or self.schedule_iterations == self.iterations:
            return self
        f = self.iterations / self.schedule_iterations
        changes = {k: max(1, round(getattr(self, k) * f)) for k in SCHEDULE_PARAMS if getattr(self, k) > 0}
        if changes.get("opacity_reset_every", self.opacity_reset_every) < self.opacity_reset_min_interval:
            changes["opacity_reset_every"] = 0
        return replace(self, **changes)

    def compressed(self, iterations: int) -> CoarseConfig:
        """This config run for ``iterations`` with every step-based schedule (``SCHEDULE_PARAMS``: the
        densification window, interval and opacity reset, the floater window and interval, the SH raise, the
        position-lr decay) scaled by iterations / self.iterations: a compressed coarse run (docs/coarse.md:
        with the hull, 1000 scaled iterations reach the coarse model's test quality). Never stretched: only
        ``iterations`` changes when it is not shorter."""
        f = iterations / max(self.iterations, 1)
        if f >= 1.0:
            return replace(self, iterations=iterations)
        scaled = {k: max(1, round(getattr(self, k) * f)) for k in SCHEDULE_PARAMS if getattr(self, k) > 0}
        return replace(self, iterations=iterations, **scaled)

    def fingerprint(self) -> str:
        import hashlib
        import json

        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()[:16]
