"""Prior-free sparse-view regularisers of the coarse stage, one small function each (each one a step param,
so each is also an ablation; measured on the dev scenes in docs/coarse.md).

* **DropGaussian** (Park et al., CVPR 2025): each training render drops every Gaussian independently with
  probability ``r_t = γ·t/T`` (rising linearly over the ``T`` iterations) and scales the opacity of the kept
  ones by ``1/(1 − r_t)``, so that each Gaussian's expected opacity equals the one rendered at test time,
  where nothing is dropped (the authors' code multiplies the activated opacity by ``Dropout(p=r_t)`` applied
  to ones, i.e. exactly this).
* **Outside-mask alpha** (silhouette tightening): ``mean over pixels outside the training mask of α²`` —
  normalised by the number of outside pixels (the BCE term averages over the whole image, so a thin band of
  stray alpha along the silhouette weighs little there).
* **Inside-mask alpha** (no see-through holes): ``mean over the eroded mask interior of (1 − α)²``; the
  erosion (``inside_erode_px``) keeps it off the edge band where a binary mask of a real photo is wrong by
  a pixel or two.
* **Anisotropy**: ``mean_i max(s_max,i / s_min,i − r, 0)`` against needle-like Gaussians (ratio ``r``).
* **Flattening** and **depth–normal consistency**: go_core.coarse.depth_normal.
* **Opacity entropy**: ``mean_i H(σ(o_i))`` towards opaque-or-gone Gaussians (a geometry candidate).
* **Opacity decay**: ``mean_i σ(o_i)``; Gaussians that no training view needs (hidden behind the surface,
  inside the hull's excess) get only this gradient and fade until pruning removes them.
"""

from __future__ import annotations

import torch

from go_core.coarse.depth_normal import flatten_loss
from go_core.coarse.settings import RegularizerConfig
from go_core.gaussians import Gaussians

__all__ = ["RegularizerConfig", "drop_compensation", "drop_rate", "regularization_loss"]


# DropGaussian ----------------------------------------------------------------------------------------------
def drop_rate(step: int, iterations: int, gamma: float) -> float:
    """DropGaussian's rate at training iteration ``step`` (1..iterations): ``γ·step/iterations`` in [0, γ]."""
    if gamma <= 0.0 or iterations <= 0:
        return 0.0
    return gamma * min(max(step, 0), iterations) / iterations


def drop_compensation(n: int, rate: float, generator: torch.Generator) -> torch.Tensor | None:
    """Per-Gaussian opacity factors [n] for one training render: 0 with probability ``rate`` (dropped), else
    ``1/(1 − rate)``; their expectation is 1 for every Gaussian (unbiased against the test-time render,
    which uses factor 1). None when ``rate`` is 0 (no draw from ``generator``: the run is bit-identical)."""
    if rate <= 0.0:
        return None
    if not rate < 1.0:
        raise ValueError(f"DropGaussian rate must be below 1, got {rate}")
    keep = torch.rand(n, generator=generator) >= rate
    return keep.to(torch.float32) / (1.0 - rate)


# Loss terms ------------------------------------------------------------------------------------------------
def outside_alpha_loss(alpha: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """``Σ (1 − m)·α² / Σ (1 − m)``: rendered alpha where the (possibly fractional) training mask says
    background, averaged over the background. Zero when the mask covers the whole image."""
    a = alpha.reshape(mask.shape)
    w = 1.0 - mask.to(a.dtype)
    return (w * a * a).sum() / w.sum().clamp_min(1.0)


def eroded_mask(mask: torch.Tensor, radius: int) -> torch.Tensor:
    """Binary [H,W] interior of ``mask`` (> 0.5): the pixels whose (2r+1)² square lies inside the mask."""
    inside = (mask > 0.5).to(torch.float32)
    if radius <= 0:
        return inside
    k = 2 * radius + 1
    outside = torch.nn.functional.max_pool2d((1.0 - inside)[None, None], k, stride=1, padding=radius)
    return 1.0 - outside[0, 0]


def inside_alpha_loss(alpha: torch.Tensor, interior: torch.Tensor) -> torch.Tensor:
    """``Σ w·(1 − α)² / Σ w`` with ``w`` the (eroded) mask interior: transparency where the training view
    sees the object, averaged over the interior. Zero for an empty interior."""
    a = alpha.reshape(interior.shape)
    w = interior.to(a.dtype)
    r = 1.0 - a
    return (w * r * r).sum() / w.sum().clamp_min(1.0)


def anisotropy_loss(log_scales: torch.Tensor, max_ratio: float) -> torch.Tensor:
    """``mean_i max(exp(max log s_i − min log s_i) − r, 0)``: penalises Gaussians whose largest axis is more
    than ``r`` times their smallest (needles and flakes that fit 4 views but not a fifth)."""
    ls = log_scales
    ratio = torch.exp(ls.max(dim=1).values - ls.min(dim=1).values)
    return torch.relu(ratio - max_ratio).mean()


def opacity_decay_loss(opacity_logits: torch.Tensor) -> torch.Tensor:
    """Mean activated opacity."""
    return torch.sigmoid(opacity_logits).mean()


def opacity_entropy_loss(opacity_logits: torch.Tensor) -> torch.Tensor:
    """``mean_i H(σ(o_i))``, the binary entropy (nats) of each opacity: pushes opacities towards 0 or 1, so
    the surface is opaque from every side and what lies behind it fades (SuGaR's entropy term)."""
    p = torch.sigmoid(opacity_logits)
    return -(
        p * torch.nn.functional.logsigmoid(opacity_logits)
        + (1 - p) * torch.nn.functional.logsigmoid(-opacity_logits)
    ).mean()


def regularization_loss(
    config: RegularizerConfig,
    gaussians: Gaussians,
    alpha: torch.Tensor,
    mask: torch.Tensor | None,
    extent: float,
) -> tuple[torch.Tensor | None, dict[str, float]]:
    """The enabled loss terms for one training render (``alpha`` the rendered [H,W] opacity, ``mask`` the
    view's mask or None, ``extent`` the scene extent), weighted and summed; None when none is enabled. Also
    returns each term's value. (The depth–normal term needs a second render: go_core.coarse.loop.)"""
    total: torch.Tensor | None = None
    parts: dict[str, float] = {}

    def add(name: str, weight: float, term: torch.Tensor) -> None:
        nonlocal total
        parts[name] = term.item()
        total = weight * term if total is None else total + weight * term

    if config.lambda_outside > 0 and mask is not None:
        add("outside_alpha", config.lambda_outside, outside_alpha_loss(alpha, mask))
    if config.lambda_inside > 0 and mask is not None:
        interior = eroded_mask(mask, config.inside_erode_px)
        add("inside_alpha", config.lambda_inside, inside_alpha_loss(alpha, interior))
    if config.lambda_anisotropy > 0:
        term = anisotropy_loss(gaussians.log_scales, config.max_anisotropy)
        add("anisotropy", config.lambda_anisotropy, term)
    if config.lambda_opacity > 0:
        add("opacity", config.lambda_opacity, opacity_decay_loss(gaussians.opacity_logits))
    if config.lambda_opacity_entropy > 0:
        add("opacity_entropy", config.lambda_opacity_entropy, opacity_entropy_loss(gaussians.opacity_logits))
    if config.lambda_flatten > 0:
        add("flatten", config.lambda_flatten, flatten_loss(gaussians.log_scales, extent))
    return total, parts


__all__ = [
    "RegularizerConfig",
    "anisotropy_loss",
    "drop_compensation",
    "drop_rate",
    "eroded_mask",
    "inside_alpha_loss",
    "opacity_decay_loss",
    "opacity_entropy_loss",
    "outside_alpha_loss",
    "regularization_loss",
]
