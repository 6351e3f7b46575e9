"""The repair loss L_rep = w(t) · λ(π) · (L1 + L2 + LPIPS) between a render and its repaired image."""

from __future__ import annotations

from collections.abc import Callable

import torch

LpipsFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def repair_image_loss(
    render: torch.Tensor,
    repaired: torch.Tensor,
    lpips: LpipsFn | None = None,
    l1_weight: float = 1.0,
    l2_weight: float = 1.0,
    lpips_weight: float = 1.0,
) -> torch.Tensor:
    """L1 + L2 (+ LPIPS when given) of images [B, 3, H, W] in [0, 1]; ``repaired`` is a fixed target."""
    target = repaired.detach()
    loss = l1_weight * (render - target).abs().mean() + l2_weight * ((render - target) ** 2).mean()
    if lpips is not None and lpips_weight > 0:
        loss = loss + lpips_weight * lpips(render, target).mean()
    return loss
