"""Gaussian repair (paper Sec. 3.5): distill the repair model into the Gaussians along distance-aware paths.

Built on ``go_core.coarse.loop.optimize`` (the reference views keep their coarse-stage loss each iteration)
plus an ``extra_loss`` hook that, during the first ``repair_iterations`` (2800 of 4000), adds for one cached
repaired view

    decay(step) · w(t) · λ(π) · (L1 + L2 + LPIPS)(render(π), repaired(π))

with decay linear 1.0 → 0.1, w(t) = 1 − ᾱ_t (DreamFusion), λ(π) = 2·min_i‖π − π_i‖ / d_max. Every
``refresh_every`` (200) iterations the cache is rebuilt from the current Gaussians: ``views_per_arc`` (2)
novel views from the middle 80% of each arc of the training-camera ellipse are rendered, put in a square
frame, noised to a random t (SDEdit) and denoised by DDIM for ⌊50·t/T⌋ steps with the ControlNet on the
render. Refreshed caches are saved in the checkpoint folder, so a resumed run reuses them exactly.

With a one-pass repair model (the compact restorer, ``go_core.compact.engine.CompactRepair``) there is no
noise level: each novel view gets a blend strength b ~ U(strength_range), the repaired image is
render + b·(restore(render) − render), and b takes w(t)'s place (w = b: the fraction of the image the model
replaces, as 1 − ᾱ_t is the fraction of signal SDEdit replaces by noise). λ(π), the decay and the refresh
schedule are unchanged. A repair prior (go_core.compact.prior, ``channels`` 4 or 8) also gets the render's
alpha, and with 8 channels the nearest training view warped through the render's expected depth
(go_core.compact.reference); its repaired alpha is kept with the view and ``alpha_weight`` · L1(alpha) joins
the view's image loss (the mask target of issue 34). Given further models of the scene (``consensus``), each
novel view's repair input is what all the models render (go_core.repair.consensus), not the render alone.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from go_core.camera import Camera
from go_core.diffusion.frame import Frame
from go_core.diffusion.sampler import RepairDiffusion
from go_core.gaussians import Gaussians
from go_core.repair.arcs import RepairArcs, with_raised_twins
from go_core.repair.consensus import agreed_render
from go_core.repair.data import (
    bchw_to_hwc,
    framed_input,
    hwc_to_bchw,
    render_differentiable,
    render_rgb_alpha_depth,
)
from go_core.repair.loss import LpipsFn, repair_image_loss
from go_core.repair.settings import RepairSettings
from go_core.repair.weights import distance_weight, lrep_decay, neighbour_dmax
from go_core.seeding import numpy_rng, torch_generator


@dataclass
class CachedView:
    camera: Camera
    image: torch.Tensor  # repaired [H, W, 3]
    render: torch.Tensor  # the render it was made from [H, W, 3]
    timestep: int  # DDIM: the SDEdit timestep; one-pass models: round(1000 · blend strength)
    w: float
    lam: float
    arc: int
    alpha: torch.Tensor | None = None  # mask target [H, W]: the repaired alpha of a restorer that gives one


def _cam_to_dict(c: Camera) -> dict:
    return {
        "name": c.name,
        "width": c.width,
        "height": c.height,
        "K": c.K.tolist(),
        "world_to_cam": c.world_to_cam.tolist(),
    }


def _cam_from_dict(d: dict) -> Camera:
    return Camera(d["name"], d["width"], d["height"], np.array(d["K"]), np.array(d["world_to_cam"]))


class RepairCache:
    """The repaired views of one refresh period, made from the Gaussians at the period's first iteration."""

    def __init__(
        self,
        arcs: RepairArcs,
        diffusion: RepairDiffusion,
        settings: RepairSettings,
        seed: int,
        directory: Path | None,
        sh_degree: int,
        references=None,
        consensus: Sequence[Gaussians] = (),
    ) -> None:
        self.arcs = arcs
        self.references = references  # ReferenceViews for a prior with a reference input, else None
        self.consensus = tuple(consensus)  # further models of the scene: restore what all render
        self.diffusion = diffusion
        self.settings = settings
        self.seed = int(seed)
        self.directory = directory
        self.sh_degree = sh_degree
        self.refs = arcs.reference_positions()
        self.d_max = neighbour_dmax(self.refs)
        self.period = -1
        self.views: list[CachedView] = []
        self.made = 0

    def _path(self, period: int) -> Path | None:
        return None if self.directory is None else self.directory / f"refresh_{period:05d}.pt"

    def ensure(self, period: int, g: Gaussians) -> None:
        if period == self.period:
            return
        path = self._path(period)
        data = None
        if path is not None and path.is_file():
            from go_core.io.checkpoint import try_load_checkpoint

            data = try_load_checkpoint(path)  # tensors and plain containers only: never code
        if isinstance(data, list):
            self.views = [
                CachedView(
                    _cam_from_dict(v["camera"]),
                    v["image"].float(),
                    v["render"].float(),
                    v["timestep"],
                    v["w"],
                    v["lam"],
                    v["arc"],
                    None if v.get("alpha") is None else v["alpha"].float(),
                )
                for v in data
            ]
        else:
            self.views = self.make(period, g)
            for v in self.views:  # the stored precision, so a resumed run (which reads the file) is identical
                v.image, v.render = v.image.half().float(), v.render.half().float()
                v.alpha = None if v.alpha is None else v.alpha.half().float()
            if path is not None:
                from go_core.io.atomic import atomic_torch_save

                atomic_torch_save(
                    path,
                    [
                        {
                            "camera": _cam_to_dict(v.camera),
                            "image": v.image.half(),
                            "render": v.render.half(),
                            "timestep": v.timestep,
                            "w": v.w,
                            "lam": v.lam,
                            "arc": v.arc,
                            "alpha": None if v.alpha is None else v.alpha.half(),
                        }
                        for v in self.views
                    ],
                )
            self.made += 1
        self.period = period

    @torch.no_grad()
    def make(self, period: int, g: Gaussians) -> list[CachedView]:
        s = self.settings
        rng = numpy_rng(self.seed, "repair_views", period)
        gen = torch_generator(self.seed, "repair_views", period)
        out = []
        with_alpha = self.restorer_gives_alpha
        views = self.arcs.sample(rng, s.views_per_arc, name_prefix=f"repair_{period}")
        if s.lift_deg:
            views = with_raised_twins(views, self.arcs.ellipse, s.lift_deg)
        for rv in views:
            rgb, alpha, depth = render_rgb_alpha_depth(g, rv.camera, s.backend, self.sh_degree)
            if self.consensus:
                others = [
                    render_rgb_alpha_depth(m, rv.camera, s.backend, m.sh_degree)[:2] for m in self.consensus
                ]
                rgb, alpha = agreed_render([(rgb, alpha), *others])
            frame = Frame.choose(rv.camera.height, rv.camera.width, alpha)
            base = hwc_to_bchw(rgb)
            reference = None
            if self.references is not None:  # the nearest training view warped through the render's depth
                reference = tuple(torch.from_numpy(a) for a in self.references.warp(rv.camera, depth, alpha))
            square = framed_input(
                frame, self.diffusion.square_side(s), rgb, alpha if with_alpha else None, reference
            )
            if with_alpha:
                base = torch.cat([base, alpha[None, None]], 1)
            images, label, w = self.diffusion.restore(square.to(self.diffusion.device), rng, gen, s)
            full = bchw_to_hwc(frame.from_square(images.float().cpu(), base))
            out.append(
                CachedView(
                    rv.camera,
                    full[..., :3].contiguous(),
                    rgb,
                    label,
                    w,
                    distance_weight(rv.camera.center, self.refs, self.d_max),
                    rv.arc,
                    full[..., 3].contiguous() if with_alpha else None,
                )
            )
        return out

    @property
    def restorer_gives_alpha(self) -> bool:
        """A repair prior: RGB + alpha in and out (4 or 8 channels)."""
        return getattr(self.diffusion, "channels", 3) >= 4

    @property
    def alpha_target_weight(self) -> float:
        """The weight of its views' mask target: ``alpha_weight`` where the restorer gives alpha (a repair
        prior); 0 otherwise (those views have no mask target: docs/decisions/0041)."""
        return self.settings.alpha_weight if self.restorer_gives_alpha else 0.0


def _references(engine, views: list):
    """ReferenceViews of the training views when the repair model takes a reference input (8 channels)."""
    if getattr(engine, "channels", 3) != 8:
        return None
    from go_core.compact.reference import ReferenceViews

    return ReferenceViews(views)


def _summary(settings: RepairSettings, arcs: RepairArcs, cache: RepairCache, stats) -> dict:
    """The repair's record that depends only on its inputs (identical after a resume): settings, arcs,
    the last refreshed views and the training counts."""
    return {
        "settings": asdict(settings),
        "arcs": [
            {
                "start_deg": round(float(np.degrees(arcs.arc_bounds(i)[0])), 3),
                "length_deg": round(float(np.degrees(arcs.arc_bounds(i)[1])), 3),
            }
            for i in range(len(arcs))
        ],
        "d_max": cache.d_max,
        "refreshes": -(
            -min(settings.repair_iterations, settings.iterations) // max(settings.refresh_every, 1)
        ),
        "last_views": [
            {
                "name": v.camera.name,
                "arc": v.arc,
                "t": v.timestep,
                "w": round(v.w, 6),
                "lambda": round(v.lam, 6),
            }
            for v in cache.views
        ],
        "train": {
            "final_count": stats.final_count,
            "densify": stats.densify,
            "loss_log": stats.loss_log[-5:],
        },
    }


@dataclass
class _RepairLoss:
    """The repair step's ``extra_loss``: L_rep on one cached repaired view (or SDS on one novel view) per
    iteration during the first ``repair_iterations``, with λ(π) and the linear decay; keeps the L_rep log."""

    arcs: RepairArcs
    cache: RepairCache
    diffusion: RepairDiffusion
    settings: RepairSettings
    seed: int
    sh: int
    lpips: LpipsFn | None
    log: list[dict]

    def __call__(self, step: int, g: Gaussians, out, view, index: int) -> torch.Tensor | None:
        s = self.settings
        if step > s.repair_iterations:
            return None
        if s.loss == "sds":
            return self.sds(step, g)
        self.cache.ensure((step - 1) // max(s.refresh_every, 1), g.detach())
        pick = numpy_rng(self.seed, "repair_pick", step).integers(len(self.cache.views))
        cv = self.cache.views[int(pick)]
        rgb, alpha = render_differentiable(g, cv.camera, 1.0, s.backend, self.sh)
        lpips_weight = self.diffusion.lpips_weight(s)
        img = repair_image_loss(hwc_to_bchw(rgb), hwc_to_bchw(cv.image), self.lpips, s.l1, s.l2, lpips_weight)
        weight = self.cache.alpha_target_weight
        if cv.alpha is not None and weight > 0:  # the repaired or agreed alpha as a mask target
            img = img + weight * (alpha - cv.alpha).abs().mean()
        loss = self.decay(step) * cv.w * cv.lam * img
        if step % 100 == 0:
            self.log.append(
                {
                    "step": step,
                    "l_rep": round(float(loss.detach()), 6),
                    "w": round(cv.w, 4),
                    "lambda": round(cv.lam, 4),
                    "t": cv.timestep,
                }
            )
        return loss

    def decay(self, step: int) -> float:
        s = self.settings
        return lrep_decay(step - 1, s.repair_iterations, s.lrep_start, s.lrep_end)

    def sds(self, step: int, g: Gaussians) -> torch.Tensor:
        """Score distillation on one novel view of the repair paths (same λ(π) and decay as L_rep)."""
        s = self.settings
        rng = numpy_rng(int(self.seed), "sds", step)
        gen = torch_generator(int(self.seed), "sds", step)
        views = self.arcs.sample(rng, 1, name_prefix=f"sds_{step}")
        rv = views[int(rng.integers(len(views)))]
        rgb, alpha = render_differentiable(g, rv.camera, 1.0, s.backend, self.sh)
        frame = Frame.choose(rv.camera.height, rv.camera.width, alpha.detach())
        square = frame.to_square(hwc_to_bchw(rgb), s.sd15_resolution).to(self.diffusion.device)
        loss_sds, t = self.diffusion.sds_loss(square, float(rng.uniform(*s.sd15_t_range)), gen)
        lam = distance_weight(rv.camera.center, self.cache.refs, self.cache.d_max)
        if step % 100 == 0:
            self.log.append(
                {"step": step, "sds": round(float(loss_sds.detach()), 6), "lambda": round(lam, 4), "t": t}
            )
        return (self.decay(step) * lam * loss_sds).cpu()


def repair_gaussians(
    coarse: Gaussians,
    views: list,
    diffusion: RepairDiffusion,
    settings: RepairSettings,
    seed: int,
    checkpoint_dir: Path | None = None,
    lpips: LpipsFn | None = None,
    on_progress: Callable[[int, dict], None] | None = None,
    consensus: Sequence[Gaussians] = (),
) -> tuple[Gaussians, dict, dict]:
    """Run the repair optimisation; returns (repaired Gaussians, summary, run facts). With ``consensus``
    (further models of the scene) each novel view's repair input is what all the models render
    (consensus.py).

    The summary depends only on the inputs (identical after a resume); the run facts (resume point, refreshes
    computed in this process, L_rep log) describe this particular process."""
    from go_core.coarse.loop import optimize
    from go_core.io.checkpoint import CheckpointSpec

    arcs = RepairArcs.from_cameras([v.camera for v in views], keep=settings.keep)
    sh = coarse.sh_degree
    cache = RepairCache(
        arcs,
        diffusion,
        settings,
        seed,
        None if checkpoint_dir is None else Path(checkpoint_dir) / "refresh",
        sh,
        _references(diffusion, views),
        consensus,
    )
    extra = _RepairLoss(arcs, cache, diffusion, settings, seed, sh, lpips, log=[])
    config = settings.training_config(sh)
    gen = torch_generator(int(seed), "repair_training")
    ckpt = (
        None
        if checkpoint_dir is None
        else CheckpointSpec(Path(checkpoint_dir) / "gs", every=settings.checkpoint_every)
    )
    result, stats = optimize(
        coarse,
        views,
        config,
        generator=gen,
        extra_loss=extra,
        on_progress=on_progress,
        checkpoint=ckpt,
        start_sh_degree=sh,
    )
    summary = _summary(settings, arcs, cache, stats)
    facts = {
        "resumed_from": stats.resumed_from,
        "refreshes_made": cache.made,
        "l_rep_log": extra.log[-20:],
        "cache": cache,
        "loss_log": stats.loss_log,  # every logged step (restored on resume): the training curves
    }
    return result, summary, facts
