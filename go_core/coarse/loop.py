"""A reusable 3DGS optimisation loop (the coarse stage; the leave-one-out and repair stages build on it).

    from go_core.coarse.loop import CoarseConfig, TrainView, optimize
    views = [TrainView.from_arrays(v.camera, v.image, mask) for v, mask in zip(scene.train, masks)]
    gaussians, stats = optimize(init_gaussians, views, CoarseConfig(iterations=10_000),
                                generator=torch_generator(seed),
                                checkpoint=CheckpointSpec(ctx.checkpoint_dir, every=500))

Per iteration (3DGS): pick one view (a random permutation of the views, refilled when empty, drawn from the
explicit ``generator``), render it over a random background (the GT is composited over the same colour with
its mask), loss = w·[(1-λs)·L1 + λs·D-SSIM] + λm·BCE(alpha, mask) + λd·depth loss (+ ``extra_loss``),
backward, densification statistics, Adam step, then densify/prune/opacity-reset and floater elimination.

Composability:
* ``TrainView.weight`` scales a view's photometric loss; ``mask_weight`` / ``depth`` are per view, so extra
  supervised images (e.g. repaired renders without a mask) can be mixed in with their own weights;
* ``sample_view(step, generator) -> index`` replaces the default view order;
* ``extra_loss(step, gaussians, out, view, index) -> Tensor | None`` adds any term;
* ``strategy`` replaces the densification strategy (``None`` → ``DensifyStrategy(config)``; pass
  ``NoDensify()`` to keep the set fixed);
* ``checkpoint`` = ``CheckpointSpec(dir, every)``: the loop resumes from the newest checkpoint in ``dir``
  (params, Adam moments, strategy state, RNG state, loss log) and its final result is bit-identical to an
  uninterrupted run.
"""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import math
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field

import numpy as np
import torch

from go_core.camera import Camera
from go_core.coarse.color_correction import ViewColorCorrection
from go_core.coarse.densify import DensifyStrategy, NoDensify, Strategy, screen_size_limit
from go_core.coarse.depth_normal import camera_normals, depth_normal_loss, valid_pixels
from go_core.coarse.floaters import FloaterElimination
from go_core.coarse.losses import depth_loss, photometric_terms
from go_core.coarse.optim import GaussianOptimizer
from go_core.coarse.regularizers import drop_compensation, drop_rate, eroded_mask, regularization_loss
from go_core.coarse.settings import CoarseConfig
from go_core.gaussians import Gaussians
from go_core.io.checkpoint import Checkpoints, CheckpointSpec, fingerprint_of

CHECKPOINT = ("ckpt", 1)  # checkpoint file prefix and format


@dataclass
class TrainView:
    """One supervised image. ``image`` float32 [H,W,3] (straight colour); ``mask`` float32 [H,W] or None
    (no mask: the image is used as is, no BCE term, any background); ``depth`` an optional monocular
    DISPARITY prior [H,W] (larger = closer; only its ranks up to shift/scale matter)."""

    camera: Camera
    image: torch.Tensor
    mask: torch.Tensor | None = None
    depth: torch.Tensor | None = None
    weight: float = 1.0  # photometric loss weight
    mask_weight: float | None = None  # BCE weight; None → config.lambda_mask

    @staticmethod
    def from_arrays(camera: Camera, image, mask=None, depth=None, **kw) -> TrainView:
        def t(a):
            return None if a is None else torch.as_tensor(np.asarray(a, np.float32))

        return TrainView(camera, t(image), t(mask), t(depth), **kw)


@dataclass
class TrainStats:
    iterations: int = 0
    resumed_from: int = 0
    initial_count: int = 0
    final_count: int = 0
    max_count: int = 0
    floaters_removed: int = 0
    floater_passes: list[dict] = field(default_factory=list)
    densify: dict[str, int] = field(default_factory=dict)
    loss_log: list[dict] = field(default_factory=list)
    depth_loss_used: bool = False
    pose_corrections: list[list[float]] | None = None  # refine_poses: per view [ωx,ωy,ωz,τx,τy,τz]
    color_transforms: list[list[float]] | None = None  # color_correction: per view [A row-major, b]

    def to_dict(self) -> dict:
        return asdict(self)

    def check_not_collapsed(self, share: float = 0.01) -> None:
        """Raise ``CollapsedModelError`` when fewer than ``share`` of the initial Gaussians survived: pruning
        emptied the model (seen with opacity resets + opacity decay at 10 000 iterations on a white object
        on white, docs/coarse.md), and renders of it would be scored as if it were a reconstruction."""
        if self.final_count < max(1, share * self.initial_count):
            from go_core.errors import CollapsedModelError

            raise CollapsedModelError(
                f"the model collapsed: {self.final_count} of {self.initial_count} Gaussians left after "
                f"{self.iterations} iterations (densify: {self.densify}); pruning removed the object — try "
                "fewer iterations, coarse.lambda_opacity=0, coarse.opacity_reset_every=0 or a larger "
                "coarse.max_screen_fraction (densify.pruned counts every prune rule)"
            )


def scene_extent(cameras: list[Camera]) -> float:
    """3DGS 'cameras extent': 1.1 × the largest distance of a camera centre from their mean."""
    centers = np.stack([c.center for c in cameras])
    radius = float(np.linalg.norm(centers - centers.mean(0), axis=1).max())
    return 1.1 * radius if radius > 0 else 1.0


def _render(
    gaussians: Gaussians,
    cam: Camera,
    sh_degree: int,
    background: torch.Tensor,
    backend: str,
    opacity_scale: torch.Tensor | None = None,
    viewmat: torch.Tensor | None = None,
):
    """Render one training view; ``opacity_scale`` [N] multiplies the activated opacities (DropGaussian);
    ``viewmat`` [1,4,4] replaces the camera's pose (joint pose refinement)."""
    from go_core.render import render, render_camera

    if opacity_scale is None and viewmat is None:
        return render_camera(gaussians, cam, sh_degree=sh_degree, background=background, backend=backend)
    g = gaussians
    opacities = g.opacities() if opacity_scale is None else g.opacities() * opacity_scale
    return render(
        g.means,
        g.quats,
        g.scales(),
        opacities,
        g.sh,
        cam.viewmat_tensor(device=g.means.device)[None] if viewmat is None else viewmat,
        cam.K_tensor(device=g.means.device)[None],
        cam.width,
        cam.height,
        sh_degree=sh_degree,
        background=background,
        backend=backend,
    )


def depth_normal_term(
    config: CoarseConfig,
    step: int,
    gaussians: Gaussians,
    view: TrainView,
    out,
    opacity_scale: torch.Tensor | None,
    viewmat: torch.Tensor | None,
) -> torch.Tensor | None:
    """The depth–normal consistency term (go_core.coarse.depth_normal) for this step's render ``out`` of a
    masked ``view``: a second render of the same Gaussians (same dropped set, same pose) with their camera-
    frame normals as colours. None when the term is off, not yet due or the view has no mask."""
    if config.lambda_depth_normal <= 0 or step < config.depth_normal_from or view.mask is None:
        return None
    from go_core.render import render

    g = gaussians
    vm = view.camera.viewmat_tensor(device=g.means.device)[None] if viewmat is None else viewmat
    normals = camera_normals(g.quats, g.log_scales, g.means, vm[0].detach())
    opacities = g.opacities() if opacity_scale is None else g.opacities() * opacity_scale
    K = view.camera.K_tensor(device=g.means.device)
    cam = view.camera
    n_out = render(
        g.means,
        g.quats,
        g.scales(),
        opacities,
        normals,
        vm,
        K[None],
        cam.width,
        cam.height,
        backend=config.backend,
    )
    alpha = out.alpha[0, ..., 0]
    valid = valid_pixels(alpha, eroded_mask(view.mask, config.inside_erode_px))
    return depth_normal_loss(n_out.rgb[0], out.depth[0, ..., 0], K, valid)


def view_target(view: TrainView, background: torch.Tensor) -> torch.Tensor:
    """The ground truth a render over ``background`` is compared with: image·m + bg·(1 - m)."""
    if view.mask is None:
        return view.image
    bg = background.to(view.image.dtype).expand_as(view.image)
    return torch.lerp(bg, view.image, view.mask[..., None])


def train_psnr(out, view: TrainView, background: torch.Tensor) -> float:
    """PSNR (dB) of this iteration's render of a training view against its target (for training curves)."""
    with torch.no_grad():
        mse = float(((out.rgb[0] - view_target(view, background)) ** 2).mean())
    return 100.0 if mse <= 1e-10 else -10.0 * math.log10(mse)


def view_loss(
    out, view: TrainView, background: torch.Tensor, config: CoarseConfig, step: int
) -> tuple[torch.Tensor, dict[str, float]]:
    """The coarse loss for one rendered view (see the module docstring). Returns (loss, its parts)."""
    rgb = out.rgb[0]  # [H,W,3]
    alpha = out.alpha[0, ..., 0]  # [H,W]
    gt = view_target(view, background)
    lam_m = config.lambda_mask if view.mask_weight is None else view.mask_weight
    use_bce = view.mask is not None and lam_m > 0
    l1v, ssv, bce = photometric_terms(rgb, gt, alpha if use_bce else None, view.mask if use_bce else None)
    photo = (1.0 - config.lambda_dssim) * l1v + config.lambda_dssim * (1.0 - ssv)
    loss = view.weight * photo
    parts = {"l1": l1v.item(), "ssim": ssv.item()}
    if bce is not None:
        loss = loss + lam_m * bce
        parts["mask_bce"] = bce.item()
    if view.depth is not None and config.lambda_depth > 0:
        valid = (alpha.detach() > 0.5) & ((view.mask > 0.5) if view.mask is not None else True)
        if int(valid.sum()) >= config.depth_min_pixels:
            disp = 1.0 / out.depth[0, ..., 0].clamp_min(1e-6)
            dl = depth_loss(disp, view.depth, valid)
            loss = loss + config.lambda_depth * dl
            parts["depth"] = dl.item()
    return loss, parts


@contextlib.contextmanager
def _cyclic_gc_paused(every: int = 100) -> Iterator[Callable[[int], None]]:
    """Python's automatic cyclic garbage collection off for a training loop; yields ``tick(step)``, which
    collects the youngest generation every ``every`` steps instead.

    The loop makes no reference cycles (measured: 0 unreachable objects per 100 iterations), but it allocates
    enough objects to trigger a collection every iteration, and every few hundred iterations one of them
    rescans every object of the process (~200k after importing torch, ~100 ms): ~1 ms per iteration on
    average, 3-4% of a coarse iteration. The ticks still free any cycles that callbacks (``extra_loss``,
    ``on_progress``) might make. The previous state is restored on exit."""
    was_enabled = gc.isenabled()
    gc.disable()

    def tick(step: int) -> None:
        if step % every == 0:
            gc.collect(0)

    try:
        yield tick
    finally:
        if was_enabled:
            gc.enable()


def _rng_state(generator: torch.Generator) -> torch.Tensor:
    return generator.get_state().clone()


def optimize(
    gaussians: Gaussians,
    views: list[TrainView],
    config: CoarseConfig,
    *,
    generator: torch.Generator,
    extent: float | None = None,
    strategy: Strategy | None = None,
    sample_view: Callable[[int, torch.Generator], int] | None = None,
    extra_loss: Callable[..., torch.Tensor | None] | None = None,
    on_progress: Callable[[int, dict], None] | None = None,
    checkpoint: CheckpointSpec | None = None,
    start_sh_degree: int = 0,
) -> tuple[Gaussians, TrainStats]:
    """Optimise ``gaussians`` on ``views``; returns (final Gaussians with ``config.sh_degree`` SH, stats).

    ``extent`` defaults to :func:`scene_extent` of the views' cameras (scales the position learning rate and
    the densification thresholds). ``start_sh_degree`` is the active SH degree at step 0 (raised by one every
    ``sh_increase_every`` steps up to ``config.sh_degree``). ``on_progress(step, info)`` is called every
    iteration. Deterministic on CPU for a given generator state.
    """
    if not views:
        raise ValueError("optimize needs at least one view")
    extent = scene_extent([v.camera for v in views]) if extent is None else float(extent)
    gaussians.check_renderable()  # one clear error now, not NaN gradients or silently dropped Gaussians
    g0 = gaussians.detach().to(dtype=torch.float32).with_sh_degree(config.sh_degree)
    opt = GaussianOptimizer(g0, config, extent)
    if strategy is None:
        limit = screen_size_limit(config, [v.mask for v in views])
        strategy = DensifyStrategy(config, extent, len(opt), limit)
    floaters = FloaterElimination(config)
    extras = _RunExtras.make(config, views)
    fingerprint = fingerprint_of(
        [config.fingerprint(), len(views), len(g0), start_sh_degree, f"{extent:.12g}"]
    )
    ckpts = None if checkpoint is None else Checkpoints(checkpoint, *CHECKPOINT)
    start, order, stats = _resume(ckpts, fingerprint, opt, strategy, generator, extras)
    if stats is None:
        stats = TrainStats(initial_count=len(g0), max_count=len(g0))
        stats.depth_loss_used = config.lambda_depth > 0 and any(v.depth is not None for v in views)

    fixed_bg = torch.tensor(config.background, dtype=torch.float32)
    with _cyclic_gc_paused() as gc_tick:
        for step in range(start + 1, config.iterations + 1):
            gc_tick(step)
            opt.set_means_lr(step)
            active_sh = min(config.sh_degree, start_sh_degree + (step // max(config.sh_increase_every, 1)))
            index = _next_view(step, sample_view, order, len(views), generator)
            view = views[index]
            bg = torch.rand(3, generator=generator) if config.random_background else fixed_bg
            g = opt.gaussians()
            rate = drop_rate(step, config.iterations, config.drop_gamma)
            keep_scale = drop_compensation(len(g), rate, generator)
            viewmat = extras.poses.viewmat(index, step) if extras.poses is not None else None
            out = _render(g, view.camera, active_sh, bg, config.backend, keep_scale, viewmat)
            if extras.colors is not None:
                rgb = extras.colors.apply(index, out.rgb[0], out.alpha[0, ..., 0], bg)
                out = dataclasses.replace(out, rgb=rgb[None])
            strategy.pre_backward(step, out)
            loss, parts = _training_loss(config, step, g, out, view, bg, extent, keep_scale, viewmat)
            if extra_loss is not None:
                extra = extra_loss(step, g, out, view, index)
                if extra is not None:
                    loss = loss + extra
                    parts["extra"] = extra.item()
            loss.backward()
            strategy.post_backward(step, out, view.camera.width, view.camera.height, opt)
            opt.step()
            extras.step(step)
            changed = strategy.after_step(step, opt, generator)
            floater_pass = floaters.after_step(step, opt, strategy)
            if floater_pass is not None:
                stats.floaters_removed += floater_pass["removed"]
                stats.floater_passes.append(floater_pass)
                changed = {**changed, "floaters": floater_pass["removed"]}
            stats.max_count = max(stats.max_count, len(opt))
            stats.iterations = step
            if step % max(config.log_every, 1) == 0 or step == config.iterations:
                stats.loss_log.append(_log_entry(step, loss, len(opt), out, view, bg, parts))
            if on_progress is not None:
                on_progress(step, {"loss": loss.item(), "n": len(opt), "view": index, **parts, **changed})
            if ckpts is not None and ckpts.due(step, config.iterations):
                _record_counts(stats, opt, strategy, extras)
                ckpts.save(step, fingerprint, _checkpoint(opt, strategy, generator, order, stats, extras))
    _record_counts(stats, opt, strategy, extras)
    if extras.colors is not None:
        stats.color_transforms = extras.colors.summary()
    if not math.isfinite(float(opt.params["means"].detach().sum())):
        raise FloatingPointError("coarse optimisation diverged (non-finite Gaussian positions)")
    return opt.snapshot(), stats


@dataclass
class _RunExtras:
    """What a run learns beside the Gaussians: the joint training poses (``refine_poses``) and the
    per-view colour corrections (``color_correction``); None when off."""

    poses: object | None
    colors: ViewColorCorrection | None

    @staticmethod
    def make(config: CoarseConfig, views: list[TrainView]) -> _RunExtras:
        poses = None
        if config.refine_poses:
            from go_core.poses.refine import JointPoses

            cams, lrs = [v.camera for v in views], (config.pose_lr_rotation, config.pose_lr_translation)
            poses = JointPoses(cams, *lrs, config.pose_refine_from, config.iterations)
        colors = ViewColorCorrection(len(views), config.color_lr) if config.color_correction else None
        return _RunExtras(poses, colors)

    def step(self, step: int) -> None:
        if self.poses is not None:
            self.poses.step(step)
        if self.colors is not None:
            self.colors.step()

    def state_dict(self) -> dict:
        return {
            **({"poses": self.poses.state_dict()} if self.poses is not None else {}),
            **({"colors": self.colors.state_dict()} if self.colors is not None else {}),
        }

    def load_state_dict(self, payload: dict) -> None:
        if self.poses is not None:
            self.poses.load_state_dict(payload["poses"])
        if self.colors is not None:
            self.colors.load_state_dict(payload["colors"])


def _resume(ckpts, fingerprint: str, opt, strategy, generator, extras: _RunExtras):
    """(step, view order, stats) of the newest checkpoint of this run, its state loaded into the optimiser,
    the strategy, the generator and the extras; (0, [], None) when there is none."""
    payload = None if ckpts is None else ckpts.newest(fingerprint)
    if payload is None:
        return 0, [], None
    opt.load_state_dict(payload["optimizer"])
    strategy.load_state_dict(payload["strategy"])
    generator.set_state(payload["rng"])
    extras.load_state_dict(payload)
    stats = TrainStats(**payload["stats"])
    stats.resumed_from = int(payload["step"])
    return int(payload["step"]), list(payload["order"]), stats


def _next_view(step: int, sample_view, order: list[int], count: int, generator: torch.Generator) -> int:
    """The training view of ``step``: ``sample_view``'s choice, else the next of a random permutation
    (``order`` is consumed in place and drawn again when empty)."""
    if sample_view is not None:
        return int(sample_view(step, generator))
    if not order:
        order.extend(torch.randperm(count, generator=generator).tolist())
    return order.pop()


def _training_loss(config: CoarseConfig, step: int, g, out, view: TrainView, bg, extent, keep_scale, viewmat):
    """The step's loss and its parts: the photometric (and depth) loss of ``view``, the enabled
    regularisers and the depth-normal term."""
    loss, parts = view_loss(out, view, bg, config, step)
    reg, reg_parts = regularization_loss(config, g, out.alpha[0, ..., 0], view.mask, extent)
    if reg is not None:
        loss = loss + reg
        parts.update(reg_parts)
    dn = depth_normal_term(config, step, g, view, out, keep_scale, viewmat)
    if dn is not None:
        loss = loss + config.lambda_depth_normal * dn
        parts["depth_normal"] = dn.item()
    return loss, parts


def _log_entry(step: int, loss, count: int, out, view: TrainView, bg, parts: dict) -> dict:
    return {
        "step": step,
        "loss": round(loss.item(), 6),
        "n": count,
        "psnr": round(train_psnr(out, view, bg), 4),
        **{k: round(v, 6) for k, v in parts.items()},
    }


def _record_counts(stats: TrainStats, opt, strategy, extras: _RunExtras) -> None:
    """The run's counts so far into ``stats`` (for a checkpoint, and at the end)."""
    stats.densify = dict(strategy.counts)
    stats.final_count = len(opt)
    if extras.poses is not None:
        stats.pose_corrections = extras.poses.corrections()


def _checkpoint(opt, strategy, generator, order: list[int], stats: TrainStats, extras: _RunExtras) -> dict:
    return {
        "optimizer": opt.state_dict(),
        "strategy": strategy.state_dict(),
        "rng": _rng_state(generator),
        "order": list(order),
        "stats": stats.to_dict(),
        **extras.state_dict(),
    }


__all__ = [
    "CoarseConfig",
    "NoDensify",
    "Strategy",
    "TrainStats",
    "TrainView",
    "optimize",
    "scene_extent",
    "view_loss",
]
