"""PSNR for images in [0, 1] (data range 1): ``10·log10(1 / MSE)``, optionally over a mask only."""

from __future__ import annotations

import torch


def mse(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean squared error over all elements, or over the pixels where ``mask`` > 0 (mask [H,W] or
    broadcastable to the image; fractional masks act as weights)."""
    if pred.shape != target.shape:
        raise ValueError(f"psnr: image shapes differ {tuple(pred.shape)} vs {tuple(target.shape)}")
    d = (pred.double() - target.double()) ** 2
    if mask is None:
        return d.mean()
    w = mask.double()
    if w.dim() == d.dim() - 1:
        w = w.unsqueeze(-1)
    w = w.expand_as(d)
    return (d * w).sum() / w.sum().clamp_min(1e-12)


def psnr(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> float:
    """PSNR in dB (inf for identical images)."""
    m = float(mse(pred, target, mask))
    if m <= 0.0:
        return float("inf")
    return float(10.0 * torch.log10(torch.tensor(1.0 / m, dtype=torch.float64)))
