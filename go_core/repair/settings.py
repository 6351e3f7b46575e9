"""Settings of the leave-one-out runs and of the Gaussian repair (torch-free, so they are checked at plan
time). Both build on the coarse stage's ``CoarseConfig``, which they are given explicitly: the leave-one-out
runs repeat the coarse training, the repair continues it with its own schedule."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

from go_core.coarse.settings import Backend, CoarseConfig
from go_core.config import setting

# the repair consensus's second model: its coarse fit repaired, or the coarse fit alone
# (go_core.repair.second_model)
ConsensusMember = Literal["repaired", "coarse"]


@dataclass
class LooSettings:
    phase1_iterations: int = setting(1000, ge=0, doc="N-1 views, densifying (paper/authors: 6000)")
    phase2_iterations: int = setting(500, ge=0, doc="all N views on a fixed set (paper/authors: 4000)")
    renders: int = setting(10, ge=1, doc="renders of the left-out view kept as degraded images (phase 2)")
    checkpoint_every: int = setting(500, ge=0, doc="mid-run checkpoints (each finished run is kept too)")
    compress_schedule: bool = setting(True, doc="phase 1 runs the coarse schedules scaled to its length")
    train_size: int = setting(
        0,
        ge=0,
        doc="train the runs on the views downscaled to this long side (0: as they are); the left-out "
        "view is rendered, and its photo kept, at full size",
    )
    backend: Backend = setting("auto", doc="auto: the coarse step's backend")
    coarse: CoarseConfig = setting(default_factory=CoarseConfig, doc="the coarse step's settings")

    def phase1_config(self) -> CoarseConfig:
        """The coarse training on the N-1 other views."""
        backend = self.backend if self.backend != "auto" else self.coarse.backend
        coarse = self.coarse.scaled_schedule()  # the coarse step's schedules, as it ran them
        if self.compress_schedule:
            coarse = coarse.compressed(self.phase1_iterations)
        return replace(coarse, iterations=self.phase1_iterations, schedule_iterations=0, backend=backend)

    def phase2_config(self) -> CoarseConfig:
        """Continued with all N views on a fixed set: no floater elimination (and no densification)."""
        return replace(self.phase1_config(), iterations=self.phase2_iterations, floaters=False)


@dataclass
class RepairSettings:
    iterations: int = setting(4000, ge=0)
    repair_iterations: int = setting(2800, ge=0, doc="reference + repaired views; reference only afterwards")
    loss: Literal["lrep", "sds"] = setting("lrep", doc="sds: score distillation instead of L_rep (ablation)")
    refresh_every: int = setting(200, ge=1, doc="repaired images re-made from the current Gaussians")
    views_per_arc: int = setting(2, ge=1, doc="repaired views per repair path per refresh")
    lift_deg: float = setting(
        0.0,
        ge=0,
        lt=90,
        doc="> 0: every repaired view gets a twin raised this many degrees above the training ellipse "
        "(views from above, which real captures' test views have; docs/real_captures.md)",
    )
    keep: float = setting(0.8, gt=0, le=1, doc="middle fraction of each arc between reference views sampled")
    sd15_t_range: tuple[float, float] = setting((0.1, 1.0), gt=0, le=1, doc="SD1.5: SDEdit strength t/T")
    strength_range: tuple[float, float] = setting((0.5, 1.0), gt=0, le=1, doc="compact: blend b, w = b")
    sd15_num_inference_steps: int = setting(50, ge=1, doc="SD1.5: DDIM steps of a full denoise")
    sd15_eta: float = setting(1.0, ge=0, doc="SD1.5: DDIM stochasticity")
    sd15_resolution: int = setting(512, ge=64, multiple_of=64, doc="SD1.5: side of the repaired views")
    compact_resolution: int = setting(256, ge=1, doc="compact model: side of the repaired views")
    lrep_start: float = setting(1.0, ge=0, doc="L_rep weight decays lrep_start -> lrep_end")
    lrep_end: float = setting(0.1, ge=0)
    l1: float = setting(1.0, ge=0)
    l2: float = setting(1.0, ge=0)
    sd15_lpips: float = setting(
        1.0, ge=0, doc="SD1.5: LPIPS term weight (off, and said so, without LPIPS weights)"
    )
    compact_lpips: float = setting(
        0.0, ge=0, doc="compact model: LPIPS term weight (0: no gain measured, half the step's CPU)"
    )
    alpha_weight: float = setting(
        1.0,
        ge=0,
        doc="L1 of the render's alpha to the repaired alpha of a restorer that gives one (a repair prior, "
        "docs/repair_prior.md): its mask target at each repaired view (docs/repair.md, 'The prior's alpha "
        "where the prior repairs')",
    )
    means_lr: float = setting(1.6e-6, gt=0, doc="constant position learning rate (authors' repair config)")
    densify_from: int = setting(400, ge=0, doc="appendix densification schedule")
    densify_until: int = setting(3600, ge=0)
    densify_every: int = setting(100, ge=1)
    opacity_reset_every: int = setting(
        0, ge=0, doc="0: none (a reset below min_opacity would prune the model away)"
    )
    min_opacity: float = setting(
        0.02,
        ge=0,
        lt=1,
        doc="prune below this opacity (coarse.min_opacity's role in the repair stage)",
    )
    lambda_anisotropy: float = setting(
        0.0,
        ge=0,
        doc="coarse.lambda_anisotropy's role in the repair stage; 0: off (docs/repair.md, 'The anisotropy "
        "term in the repair')",
    )
    checkpoint_every: int = setting(200, ge=0)
    backend: Backend = "auto"
    coarse: CoarseConfig = setting(default_factory=CoarseConfig, doc="the coarse step's settings")

    def check(self) -> list[str]:
        problems = [
            f"{name} must be increasing, got {list(value)}"
            for name, value in (("sd15_t_range", self.sd15_t_range), ("strength_range", self.strength_range))
            if value[0] > value[1]
        ]
        reset = self.coarse.opacity_reset_value
        last = min(self.densify_until, self.iterations)  # resets happen only while densifying
        fires = 0 < self.opacity_reset_every < last
        if fires and reset < self.min_opacity:
            problems.append(
                f"opacity_reset_every={self.opacity_reset_every} resets opacities to "
                f"coarse.opacity_reset_value {reset:g}, below min_opacity {self.min_opacity:g}: the next "
                "pruning removes every Gaussian "
                "not re-grown by then (dev/basket lost 89% of its Gaussians); lower min_opacity or set 0"
            )
        return problems

    def training_config(self, sh_degree: int) -> CoarseConfig:
        """The coarse stage's loss and learning rates with the repair schedule: constant position rate,
        the appendix densification, its own anisotropy weight, no floater elimination, no depth term."""
        return replace(
            self.coarse.scaled_schedule(),
            iterations=self.iterations,
            schedule_iterations=0,
            sh_degree=sh_degree,
            backend=self.backend,
            position_lr_init=self.means_lr,
            position_lr_final=self.means_lr,
            position_lr_max_steps=self.iterations,
            densify_from=self.densify_from,
            densify_until=self.densify_until,
            densify_every=self.densify_every,
            opacity_reset_every=self.opacity_reset_every,
            min_opacity=self.min_opacity,
            lambda_anisotropy=self.lambda_anisotropy,
            floaters=False,
            lambda_depth=0.0,
        )
