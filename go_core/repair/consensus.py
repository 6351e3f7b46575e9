"""Two models' agreement at a novel view (issue 33): the repair input a second model of the scene makes.

Two models fitted to the same four photos with different seeds agree where the photos decide the shape and
differ where they leave it open (between and above the views, inside the visual hull). ``agreed_render``
keeps only what all of them render (two or more models): alpha is the smallest, colour the alpha-weighted
mean, composited on white as the repair renders are. The repair step restores that image instead of its
own render, so the Gaussians are pulled towards the shape the models share (docs/real_captures.md: "Seeds,
three more variants, and a second seed's agreement"; more than two models: ``repair.consensus_models``)."""

from __future__ import annotations

from collections.abc import Sequence

import torch

MIN_ALPHA = 1e-3  # below this a render's colour is undefined (it is the background)


def colour_under(rgb: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """The object's colour [H,W,3] in a render ``rgb`` composited on white with ``alpha`` [H,W]."""
    a = alpha[..., None]
    return (rgb - (1.0 - a)) / a.clamp_min(MIN_ALPHA)


def agreed_render(renders: Sequence[tuple[torch.Tensor, torch.Tensor]]) -> tuple[torch.Tensor, torch.Tensor]:
    """(rgb [H,W,3] on white, alpha [H,W]) of what two or more renders (rgb on white, alpha) share: alpha =
    their minimum, colour = the mean of their colours weighted by their alphas (clamped to [0, 1])."""
    if len(renders) < 2:
        raise ValueError(f"an agreement needs two or more renders, got {len(renders)}")
    weights = [alpha[..., None] for _, alpha in renders]
    weighted = sum(colour_under(rgb, alpha) * w for (rgb, alpha), w in zip(renders, weights, strict=True))
    colour = weighted / sum(weights).clamp_min(MIN_ALPHA)
    alpha = torch.stack([alpha for _, alpha in renders]).amin(0)
    return colour.clamp(0.0, 1.0) * alpha[..., None] + (1.0 - alpha[..., None]), alpha


__all__ = ["MIN_ALPHA", "agreed_render", "colour_under"]
