"""Two models' agreement at a novel view (issue 33): the repair input a second model of the scene makes.

Two models fitted to the same four photos with different seeds agree where the photos decide the shape and
differ where they leave it open (between and above the views, inside the visual hull). ``agreed_render``
keeps only what both render: alpha is the smaller of the two, colour the alpha-weighted mean, composited on
white as the repair renders are. The repair step restores that image instead of its own render, so the
Gaussians are pulled towards the shape both models share (docs/real_captures.md: "Seeds, three more
variants, and a second seed's agreement")."""

from __future__ import annotations

import torch

MIN_ALPHA = 1e-3  # below this a render's colour is undefined (it is the background)


def colour_under(rgb: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """The object's colour [H,W,3] in a render ``rgb`` composited on white with ``alpha`` [H,W]."""
    a = alpha[..., None]
    return (rgb - (1.0 - a)) / a.clamp_min(MIN_ALPHA)


def agreed_render(
    rgb_a: torch.Tensor, alpha_a: torch.Tensor, rgb_b: torch.Tensor, alpha_b: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """(rgb [H,W,3] on white, alpha [H,W]) of what two renders on white share: alpha = min(alpha_a, alpha_b),
    colour = the mean of the two colours weighted by their alphas (clamped to [0, 1])."""
    wa, wb = alpha_a[..., None], alpha_b[..., None]
    colour = (colour_under(rgb_a, alpha_a) * wa + colour_under(rgb_b, alpha_b) * wb) / (wa + wb).clamp_min(
        MIN_ALPHA
    )
    alpha = torch.minimum(alpha_a, alpha_b)
    return colour.clamp(0.0, 1.0) * alpha[..., None] + (1.0 - alpha[..., None]), alpha


__all__ = ["MIN_ALPHA", "agreed_render", "colour_under"]
