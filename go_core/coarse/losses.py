"""The coarse-stage loss terms, one named function each (paper Sec. 3.3 + 3DGS).

Image tensors are accepted as [B,3,H,W] or [H,W,3] (a single image, channels last, as the renderer returns
per camera) or [B,H,W,3] when ``channels_last=True``; all functions are differentiable.

``ssim`` of one float32 CPU image pair runs the compiled kernel (go_core/kernels/csrc/ssim.cpp, part of the
CPU rasterizer extension: double-precision filtering and a hand-written backward, ~4x faster than the torch
path); ``ssim_map`` is the torch reference (any dtype/device/batch, autograd).
"""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F
from torch.autograd.function import once_differentiable

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01**2  # (K1·L)² with L = 1
SSIM_C2 = 0.03**2


def _as_bchw(img: torch.Tensor, channels_last: bool = False) -> torch.Tensor:
    """[H,W,C] (C in 1, 3) → [1,C,H,W]; [C,H,W] → [1,C,H,W]; [B,C,H,W] unchanged; [B,H,W,C] with
    ``channels_last``."""
    if img.dim() == 3:
        return img.permute(2, 0, 1).unsqueeze(0) if img.shape[-1] in (1, 3) else img.unsqueeze(0)
    if img.dim() == 4:
        return img.permute(0, 3, 1, 2) if channels_last else img
    raise ValueError(f"expected an image [H,W,3], [C,H,W] or a batch [B,C,H,W], got shape {tuple(img.shape)}")


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA, *, dtype=torch.float32, device=None):
    """Normalised 2D Gaussian window [size, size] (the separable 1D kernel's outer product)."""
    x = torch.arange(size, dtype=torch.float64, device=device) - (size - 1) / 2.0
    g = torch.exp(-(x**2) / (2.0 * sigma**2))
    g = g / g.sum()
    return torch.outer(g, g).to(dtype)


@functools.cache
def _window64() -> torch.Tensor:
    """The separable 1D SSIM kernel in float64 (ssim_map and the compiled kernel filter with it)."""
    return gaussian_window(dtype=torch.float64).sum(0)


def ssim_map(img1: torch.Tensor, img2: torch.Tensor, *, channels_last: bool = False) -> torch.Tensor:
    """Per-pixel SSIM [B,C,H,W] with the 3DGS settings: 11×11 Gaussian window (σ = 1.5), zero padding of 5
    pixels (the output keeps the input size), C1 = 0.01², C2 = 0.03² for images in [0, 1]."""
    a = _as_bchw(img1, channels_last)
    b = _as_bchw(img2, channels_last)
    if a.shape != b.shape:
        raise ValueError(f"ssim: image shapes differ {tuple(a.shape)} vs {tuple(b.shape)}")
    c = a.shape[1]
    g = _window64().to(device=a.device, dtype=a.dtype)  # separable 1D kernel
    pad = SSIM_WINDOW // 2

    def filt(x: torch.Tensor) -> torch.Tensor:  # grouped separable convolution == 2D filter, zero padding
        k = x.shape[1]
        wv = g.view(1, 1, SSIM_WINDOW, 1).expand(k, 1, SSIM_WINDOW, 1).contiguous()
        wh = g.view(1, 1, 1, SSIM_WINDOW).expand(k, 1, 1, SSIM_WINDOW).contiguous()
        return F.conv2d(F.conv2d(x, wv, padding=(pad, 0), groups=k), wh, padding=(0, pad), groups=k)

    # filtered maps in two batched calls: those of an image without gradient (the target) skip autograd
    if a.requires_grad and not b.requires_grad:
        with torch.no_grad():
            mu2, e22 = filt(torch.cat([b, b * b], dim=1)).split(c, dim=1)
        mu1, e11, e12 = filt(torch.cat([a, a * a, a * b], dim=1)).split(c, dim=1)
    else:
        mu1, mu2, e11, e22, e12 = filt(torch.cat([a, b, a * a, b * b, a * b], dim=1)).split(c, dim=1)
    mu1_sq, mu2_sq, mu12 = mu1 * mu1, mu2 * mu2, mu1 * mu2
    s1, s2, s12 = e11 - mu1_sq, e22 - mu2_sq, e12 - mu12
    return ((2 * mu12 + SSIM_C1) * (2 * s12 + SSIM_C2)) / ((mu1_sq + mu2_sq + SSIM_C1) * (s1 + s2 + SSIM_C2))


def _ssim_ops():
    from go_core.render.build import load_extension

    load_extension()  # registers torch.ops.go_ssim (built once per machine, cached in this process)
    return torch.ops.go_ssim


class _SSIMKernel(torch.autograd.Function):
    """Mean SSIM of one [H,W,C] float32 CPU image pair by the compiled kernel; gradient for the first only."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, y: torch.Tensor, need_grad: bool) -> torch.Tensor:
        mean, partials = _ssim_ops().forward(x, y, _window64(), SSIM_C1, SSIM_C2, need_grad)
        if need_grad:
            ctx.save_for_backward(x, y, partials)
        return mean.to(x.dtype)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad: torch.Tensor):
        x, y, partials = ctx.saved_tensors
        gx = _ssim_ops().backward(x, y, partials, _window64(), float(grad) / x.numel())
        return gx, None, None


def _kernel_applies(a: torch.Tensor, b: torch.Tensor) -> bool:
    """Whether ``ssim`` of these [B,C,H,W] tensors runs the compiled kernel: one 3-channel float32 CPU pair
    whose second image is a constant target."""
    return (
        a.device.type == "cpu"
        and b.device.type == "cpu"
        and a.dtype == torch.float32
        and b.dtype == torch.float32
        and a.shape == b.shape
        and a.shape[0] == 1
        and a.shape[1] == 3
        and a.numel() > 0
        and not (b.requires_grad and torch.is_grad_enabled())
    )


def ssim(img1: torch.Tensor, img2: torch.Tensor, *, channels_last: bool = False) -> torch.Tensor:
    """Mean SSIM (scalar tensor, differentiable) of two images or batches in [0, 1], 3DGS convention.

    Accepts [B,3,H,W], a single [H,W,3] image, or [B,H,W,3] with ``channels_last=True``. One float32 CPU
    image pair whose target (``img2``) needs no gradient runs the compiled kernel (equal to ``ssim_map``'s
    mean in float64 to ~1e-14, then rounded to float32; the renderer's [H,W,3] layout is used without a
    copy); anything else runs ``ssim_map``. Note: scikit-image's
    ``structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1)``
    averages only over pixels whose window lies inside the image; ``ssim_map(...)[..., 5:-5, 5:-5].mean()``
    equals it to float precision.
    """
    a = _as_bchw(img1, channels_last)
    b = _as_bchw(img2, channels_last)
    if _kernel_applies(a, b):
        need_grad = a.requires_grad and torch.is_grad_enabled()
        x = a.squeeze(0).permute(1, 2, 0).contiguous()  # no copy for a permuted [H,W,3] image
        y = b.detach().squeeze(0).permute(1, 2, 0).contiguous()
        return _SSIMKernel.apply(x, y, need_grad)
    return ssim_map(a, b).mean()


class _TermsKernel(torch.autograd.Function):
    """(SSIM, L1, BCE) of one [H,W,C] float32 CPU pair (and an [H,W] alpha/mask, or empty tensors) by the
    compiled kernel in one pass each way; gradients for the image and alpha only."""

    @staticmethod
    def forward(ctx, x, y, alpha, mask, eps: float, need_grad: bool):
        lo, hi = eps, 1.0 - eps
        s, l1v, bce, partials = _ssim_ops().terms_forward(
            x, y, _window64(), SSIM_C1, SSIM_C2, alpha, mask, lo, hi, need_grad
        )
        if need_grad:
            ctx.save_for_backward(x, y, partials, alpha, mask)
        ctx.bounds = (lo, hi)
        return s.to(x.dtype), l1v.to(x.dtype), bce.to(x.dtype)

    @staticmethod
    @once_differentiable
    def backward(ctx, g_ssim, g_l1, g_bce):
        x, y, partials, alpha, mask = ctx.saved_tensors
        n = x.numel()
        gx, ga = _ssim_ops().terms_backward(
            x,
            y,
            partials,
            _window64(),
            float(g_ssim) / n,
            float(g_l1) / n,
            alpha,
            mask,
            *ctx.bounds,
            float(g_bce) / max(alpha.numel(), 1),
        )
        return gx, None, ga if alpha.numel() else None, None, None, None


def _terms_kernel_applies(pred, target, alpha, mask) -> bool:
    """Whether ``photometric_terms`` runs the compiled kernel: an [H,W,3] pair that ``ssim``'s kernel takes,
    and float32 CPU alpha/mask of H·W elements (constant mask)."""
    if not (pred.dim() == 3 and pred.shape[-1] == 3 and pred.shape == target.shape):
        return False
    if not _kernel_applies(_as_bchw(pred), _as_bchw(target)):
        return False
    if alpha is None:
        return True
    hw = pred.shape[0] * pred.shape[1]
    return not (mask.requires_grad and torch.is_grad_enabled()) and all(
        t.device.type == "cpu" and t.dtype == torch.float32 and t.numel() == hw for t in (alpha, mask)
    )


def photometric_terms(
    pred: torch.Tensor,
    target: torch.Tensor,
    alpha: torch.Tensor | None = None,
    mask: torch.Tensor | None = None,
    eps: float = 1e-6,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """The per-pixel terms of the coarse loss for one view: ``(l1(pred, target), ssim(pred, target),
    mask_bce(alpha, mask, eps))``, the last None without ``alpha``/``mask``.

    ``pred``/``target`` are [H,W,3] (the renderer's layout), ``alpha`` any shape of H·W elements (e.g. the
    renderer's [H,W] or [1,H,W,1]), ``mask`` [H,W]. A float32 CPU view runs all three in one compiled pass
    forward and one backward (go_core/kernels/csrc/ssim.cpp: SSIM and L1 in float64 sums, the BCE value with
    float32 vector logs, as torch's float32 mask_bce, summed in float64; its gradient in float64), instead of
    ~30 small torch ops; anything else runs the three torch functions.
    """
    if (alpha is None) != (mask is None):
        raise ValueError("photometric_terms: give both alpha and mask, or neither")
    if not _terms_kernel_applies(pred, target, alpha, mask):
        bce = mask_bce(alpha, mask, eps) if alpha is not None else None
        return l1(pred, target), ssim(pred, target), bce
    h, w = pred.shape[:2]
    if alpha is None:
        a = m = pred.new_empty(0)
    else:
        a, m = alpha.reshape(h, w).contiguous(), mask.detach().reshape(h, w).contiguous()
    need_grad = torch.is_grad_enabled() and (pred.requires_grad or a.requires_grad)
    x, y = pred.contiguous(), target.detach().contiguous()
    s, l1v, bce = _TermsKernel.apply(x, y, a, m, float(eps), need_grad)
    return l1v, s, bce if alpha is not None else None


def l1(pred: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """Mean absolute error; with ``weight`` (broadcastable), a weighted mean."""
    d = (pred - target).abs()
    if weight is None:
        return d.mean()
    w = weight.expand_as(d)
    return (d * w).sum() / w.sum().clamp_min(1e-12)


def dssim(pred: torch.Tensor, target: torch.Tensor, *, channels_last: bool = False) -> torch.Tensor:
    """Structural dissimilarity ``1 - SSIM`` (the 3DGS loss uses this, not (1-SSIM)/2)."""
    return 1.0 - ssim(pred, target, channels_last=channels_last)


def photometric_loss(
    pred: torch.Tensor, target: torch.Tensor, lambda_dssim: float = 0.2, *, channels_last: bool = False
) -> torch.Tensor:
    """``(1-λ)·L1 + λ·D-SSIM`` (3DGS, λ = 0.2)."""
    return (1.0 - lambda_dssim) * l1(pred, target) + lambda_dssim * dssim(
        pred, target, channels_last=channels_last
    )


def mask_bce(alpha: torch.Tensor, mask: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """Binary cross-entropy between the rendered opacity and the (possibly fractional) object mask.

    Alpha and mask must have the same number of elements (alpha is reshaped to the mask's shape, e.g. the
    renderer's [1,H,W,1] against [H,W]). Alpha is clamped to [eps, 1-eps] so the loss stays finite where the
    model is fully opaque or empty.
    """
    if alpha.shape != mask.shape and alpha.numel() == mask.numel():
        alpha = alpha.reshape(mask.shape)  # e.g. the renderer's [1,H,W,1] against an [H,W] mask
    if alpha.shape != mask.shape:
        raise ValueError(f"mask_bce: alpha {tuple(alpha.shape)} and mask {tuple(mask.shape)} differ in size")
    a = alpha.clamp(eps, 1.0 - eps)
    # m·log(a) + (1-m)·log(1-a) as one lerp: the value of F.binary_cross_entropy, ~2.5x cheaper on CPU
    return -torch.lerp(torch.log1p(-a), a.log(), mask.to(a.dtype)).mean()


def normalize_depth(
    depth: torch.Tensor, valid: torch.Tensor | None = None, eps: float = 1e-8
) -> torch.Tensor:
    """Shift/scale-normalised depth ``D* = (D - median(D)) / mean(|D - median(D)|)`` over the valid pixels.

    The statistics use only ``valid`` pixels (bool, same shape) when given; the result has the input's shape
    (invalid pixels carry meaningless values, mask them out). Invariant to ``D → s·D + t`` for s > 0.
    """
    d = depth.reshape(-1)
    v = d if valid is None else d[valid.reshape(-1)]
    if v.numel() == 0:
        return torch.zeros_like(depth)
    med = v.median()
    mad = (v - med).abs().mean()
    return (depth - med) / mad.clamp_min(eps)


def depth_loss(
    rendered: torch.Tensor, prior: torch.Tensor, valid: torch.Tensor | None = None, eps: float = 1e-8
) -> torch.Tensor:
    """Shift/scale-invariant depth loss: L1 between the median/MAD-normalised rendered depth and prior,
    averaged over ``valid`` pixels (e.g. inside the mask). Both maps are per-view [H,W] (or [H,W,1])."""
    r = rendered.reshape(prior.shape) if rendered.numel() == prior.numel() else rendered
    if valid is not None:
        valid = valid.reshape(prior.shape).bool()
        if not bool(valid.any()):
            return rendered.sum() * 0.0
    nr = normalize_depth(r, valid, eps)
    npr = normalize_depth(prior, valid, eps)
    d = (nr - npr).abs()
    return d[valid].mean() if valid is not None else d.mean()


__all__ = [
    "depth_loss",
    "dssim",
    "gaussian_window",
    "l1",
    "mask_bce",
    "normalize_depth",
    "photometric_loss",
    "photometric_terms",
    "ssim",
    "ssim_map",
]
