"""Adaptive density control (3DGS clone / split / prune) as a strategy object with hooks, gsplat style.

The training loop calls ``pre_backward(step, out)`` after rendering (so the screen-space means keep their
gradient), ``post_backward(step, out, width, height)`` after ``loss.backward()`` (accumulates statistics) and
``after_step(step, opt, generator)`` after the optimiser step (changes the set: densify, prune, opacity
reset).
All state lives in ``state_dict()`` so a checkpoint resumes bit-identically.

Additions to 3DGS, both reported: a Gaussian budget (``max_gaussians``; candidates are ranked by gradient
when the budget binds) and pruning of Gaussians that contributed nothing (no colour gradient at all over a
whole densification interval: they were occluded, outside every view or transparent).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import torch

from go_core.coarse.optim import GaussianOptimizer
from go_core.coarse.settings import DensifyConfig
from go_core.render.projection import quat_to_rotmat

__all__ = ["DensifyConfig", "DensifyStrategy", "NoDensify", "Strategy", "quat_to_rotmat", "screen_size_limit"]


def screen_size_limit(config: DensifyConfig, masks: list) -> float:
    """The screen-radius (px) above which a Gaussian is pruned after the first opacity reset.

    3DGS prunes Gaussians wider than ``max_screen_size`` = 20 px, a limit written for ~1000-px photos of
    whole scenes. In pixels it depends on the resolution and the framing: on real/ethiopian_head (400 px,
    the head filling 214 px) the hull's own Gaussians are 15-20 px wide, so after the first reset ~20 % of
    them were pruned every densification interval, their clones were as wide, and the object bled away (7
    of 20 000 left; docs/coarse.md "Real captures"). With ``max_screen_fraction`` > 0 the limit is that
    fraction of the object's silhouette size, the median over the training ``masks`` of sqrt(mask area in
    px): a Gaussian wider than that share of the object is a blob or a floater at any resolution.
    ``max_screen_size`` (px) applies when the fraction is 0 or no mask is given; 0 turns the rule off."""
    import numpy as np

    sizes = [float(np.sqrt((np.asarray(m) > 0.5).sum())) for m in masks if m is not None]
    if config.max_screen_fraction <= 0 or not sizes or config.max_screen_size <= 0:
        return float(config.max_screen_size)
    return float(config.max_screen_fraction * np.median(sizes))


class Strategy(ABC):
    """What the training loop calls (see the module docstring); ``counts`` says what the strategy did."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}

    @abstractmethod
    def pre_backward(self, step: int, out) -> None: ...

    @abstractmethod
    def post_backward(self, step: int, out, width: int, height: int, opt: GaussianOptimizer) -> None: ...

    @abstractmethod
    def after_step(self, step: int, opt: GaussianOptimizer, generator: torch.Generator) -> dict[str, int]:
        """Change the set (densify, prune, reset); returns {operation: count} for this step."""

    @abstractmethod
    def on_external_prune(self, keep: torch.Tensor) -> None:
        """Rows were removed by someone else (floater elimination): drop their statistics."""

    @abstractmethod
    def state_dict(self) -> dict: ...

    @abstractmethod
    def load_state_dict(self, state: dict) -> None: ...


class NoDensify(Strategy):
    """A strategy that never changes the set (fine-tuning, repair)."""

    def pre_backward(self, step: int, out) -> None:
        pass

    def post_backward(self, step: int, out, width: int, height: int, opt: GaussianOptimizer) -> None:
        pass

    def after_step(self, step: int, opt: GaussianOptimizer, generator: torch.Generator) -> dict[str, int]:
        return {}

    def on_external_prune(self, keep: torch.Tensor) -> None:
        pass

    def state_dict(self) -> dict:
        return {}

    def load_state_dict(self, state: dict) -> None:
        pass


class DensifyStrategy(Strategy):
    """3DGS adaptive density control with a budget; see the module docstring for the hook protocol."""

    def __init__(
        self, config: DensifyConfig, extent: float, n: int, screen_limit: float | None = None
    ) -> None:
        super().__init__()
        self.config = config
        self.extent = float(extent)
        self.screen_limit = float(config.max_screen_size if screen_limit is None else screen_limit)
        self.counts: dict[str, int] = {"cloned": 0, "split": 0, "pruned": 0, "pruned_no_contribution": 0}
        self.counts.update({"opacity_resets": 0, "budget_limited": 0})
        self._reset_stats(n)

    def _reset_stats(self, n: int) -> None:
        self.grad_accum = torch.zeros(n)
        self.vis_count = torch.zeros(n)
        self.color_grad = torch.zeros(n)
        self.max_radii = torch.zeros(n)

    def active(self, step: int) -> bool:
        return step < self.config.densify_until

    # Hooks -------------------------------------------------------------------------------------------------
    def pre_backward(self, step: int, out) -> None:
        if self.active(step) and out.means2d.requires_grad:
            out.means2d.retain_grad()

    @torch.no_grad()
    def post_backward(self, step: int, out, width: int, height: int, opt: GaussianOptimizer) -> None:
        """Accumulate the NDC screen-space gradient norm, visibility and colour-gradient statistics."""
        if not self.active(step):
            return
        radii = out.radii.detach()
        if radii.dim() == 3:  # gsplat >= 1.5 returns per-axis radii [C,N,2]
            radii = radii.max(dim=-1).values
        radii = radii.reshape(-1, radii.shape[-1])  # [C,N]
        visible = radii > 0
        if out.means2d.grad is not None:
            g = out.means2d.grad.detach().reshape(-1, radii.shape[1], 2).clone()
            g[..., 0] *= width / 2.0
            g[..., 1] *= height / 2.0
            norms = g.norm(dim=-1)  # [C,N]
            self.grad_accum += (norms * visible).sum(0)
        self.vis_count += visible.sum(0).to(self.vis_count.dtype)
        self.max_radii = torch.maximum(self.max_radii, radii.max(0).values.to(self.max_radii.dtype))
        dc_grad = opt.params["sh0"].grad
        if dc_grad is not None:
            self.color_grad += dc_grad.detach().abs().reshape(len(opt), -1).sum(1)

    @torch.no_grad()
    def after_step(self, step: int, opt: GaussianOptimizer, generator: torch.Generator) -> dict[str, int]:
        """Densify / prune / reset at their steps (``step`` counts completed iterations, from 1)."""
        c = self.config
        changed: dict[str, int] = {}
        if not self.active(step):
            return changed
        if step > c.densify_from and step % c.densify_every == 0:
            changed.update(self._densify_and_prune(opt, step, generator))
            self._reset_stats(len(opt))
        if c.opacity_reset_every > 0 and step % c.opacity_reset_every == 0:
            value = torch.logit(torch.tensor(c.opacity_reset_value)).item()
            opt.reset("opacity_logits", opt.params["opacity_logits"].detach().clamp_max(value))
            self.counts["opacity_resets"] += 1
        return changed

    # Operations --------------------------------------------------------------------------------------------
    def _prune_mask(self, opt: GaussianOptimizer, step: int) -> tuple[torch.Tensor, int]:
        """Rows to remove: transparent, too big (after the first reset), or without any contribution."""
        c = self.config
        p = opt.params
        opac = torch.sigmoid(p["opacity_logits"].detach())
        prune = opac < c.min_opacity
        if step > c.opacity_reset_every > 0:
            if c.max_screen_size > 0 and self.screen_limit > 0:
                prune |= self.max_radii > self.screen_limit
            if c.max_world_size > 0:
                prune |= p["log_scales"].detach().exp().max(dim=1).values > c.max_world_size * self.extent
        n_nc = 0
        if c.prune_no_contribution:
            nothing = self.color_grad == 0
            n_nc = int((nothing & ~prune).sum())
            prune |= nothing
        if bool(prune.all()):  # never prune everything: keep the set trainable
            return torch.zeros_like(prune), 0
        return prune, n_nc

    def _densify_and_prune(
        self, opt: GaussianOptimizer, step: int, generator: torch.Generator
    ) -> dict[str, int]:
        c = self.config
        p = opt.params
        n = len(opt)
        prune, n_nc = self._prune_mask(opt, step)
        grads = self.grad_accum / self.vis_count.clamp_min(1.0)
        high = (grads >= c.densify_grad_threshold) & ~prune
        max_scale = p["log_scales"].detach().exp().max(dim=1).values
        small = max_scale <= c.percent_dense * self.extent
        clone = high & small
        split = high & ~small
        # Budget: a clone adds one Gaussian, a split adds split_count - 1; keep the highest gradients.
        if c.max_gaussians > 0:
            room = c.max_gaussians - (n - int(prune.sum()))
            growth = clone.to(torch.int64) + split.to(torch.int64) * (c.split_count - 1)
            if int(growth.sum()) > room:
                self.counts["budget_limited"] += 1
                ranked = torch.where(high, grads, torch.full_like(grads, -1.0))
                order = torch.argsort(ranked, descending=True, stable=True)
                allowed = torch.cumsum(growth[order], 0) <= max(room, 0)
                chosen = torch.zeros(n, dtype=torch.bool)
                chosen[order[allowed]] = True
                clone &= chosen
                split &= chosen
        n_clone, n_split = int(clone.sum()), int(split.sum())
        new_rows: list[dict[str, torch.Tensor]] = []
        if n_clone:
            new_rows.append({k: v.detach()[clone] for k, v in p.items()})
        if n_split:
            k = c.split_count
            idx = torch.nonzero(split).squeeze(1)
            scales = p["log_scales"].detach()[idx].exp()
            rot = quat_to_rotmat(p["quats"].detach()[idx])
            samples = torch.randn((k, idx.numel(), 3), generator=generator) * scales
            offsets = torch.einsum("nij,knj->kni", rot, samples)
            rows = {name: t.detach()[idx].repeat(k, *([1] * (t.dim() - 1))) for name, t in p.items()}
            rows["means"] = (p["means"].detach()[idx].unsqueeze(0) + offsets).reshape(-1, 3)
            rows["log_scales"] = torch.log(scales / (0.8 * k)).repeat(k, 1)
            new_rows.append(rows)
        n_new = 0
        if new_rows:
            merged = {k: torch.cat([r[k] for r in new_rows]) for k in p}
            n_new = merged["means"].shape[0]
            opt.append(merged)
        remove = prune | split
        if bool(remove.any()):
            opt.keep(torch.cat([~remove, torch.ones(n_new, dtype=torch.bool)]))
        n_pruned = int(prune.sum())
        self.counts["cloned"] += n_clone
        self.counts["split"] += n_split
        self.counts["pruned"] += n_pruned - n_nc
        self.counts["pruned_no_contribution"] += n_nc
        return {"cloned": n_clone, "split": n_split, "pruned": n_pruned}

    def on_external_prune(self, keep: torch.Tensor) -> None:
        """Keep the statistics aligned when someone else removes rows (floater elimination)."""
        for name in ("grad_accum", "vis_count", "color_grad", "max_radii"):
            t = getattr(self, name)
            if t.numel() == keep.numel():
                setattr(self, name, t[keep])

    # Persistence -------------------------------------------------------------------------------------------
    def state_dict(self) -> dict:
        return {
            "grad_accum": self.grad_accum.clone(),
            "vis_count": self.vis_count.clone(),
            "color_grad": self.color_grad.clone(),
            "max_radii": self.max_radii.clone(),
            "counts": dict(self.counts),
            "extent": self.extent,
        }

    def load_state_dict(self, state: dict) -> None:
        self.grad_accum = state["grad_accum"].clone()
        self.vis_count = state["vis_count"].clone()
        self.color_grad = state["color_grad"].clone()
        self.max_radii = state["max_radii"].clone()
        self.counts = dict(state["counts"])
        self.extent = float(state["extent"])
