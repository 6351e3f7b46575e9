"""SSIM as an evaluation metric. Reuses the one differentiable 3DGS SSIM (``go_core.coarse.losses.ssim_map``:
11×11 Gaussian window, σ = 1.5, zero padding) so training and evaluation measure the same thing.

``border="pad"`` (the 3DGS / GaussianObject evaluation) averages the full zero-padded map;
``border="valid"`` averages only pixels whose window lies inside the image, which equals scikit-image's
``structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1)``.
"""

from __future__ import annotations

import torch

from go_core.coarse.losses import SSIM_WINDOW, ssim_map


def ssim_metric_map(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per-pixel SSIM [H,W] (channel mean) of two [H,W,3] images in [0, 1], computed in float64."""
    return ssim_map(pred.double(), target.double())[0].mean(0)


def ssim(
    pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None, border: str = "pad"
) -> float:
    """Mean SSIM of two [H,W,3] images; with ``mask`` [H,W], the mask-weighted mean of the SSIM map."""
    return reduce_ssim_map(ssim_metric_map(pred, target), mask, border)


def reduce_ssim_map(smap: torch.Tensor, mask: torch.Tensor | None = None, border: str = "pad") -> float:
    """Mean (or mask-weighted mean) of an SSIM map [H,W] under the ``border`` convention."""
    if border == "valid":
        r = SSIM_WINDOW // 2
        smap = smap[r:-r, r:-r]
        if mask is not None:
            mask = mask[r:-r, r:-r]
    elif border != "pad":
        raise ValueError(f"ssim border must be 'pad' or 'valid', got {border!r}")
    if mask is None:
        return float(smap.mean())
    w = mask.double()
    return float((smap * w).sum() / w.sum().clamp_min(1e-12))
