"""The compiled one-pass versions of the coarse loss's per-pixel terms and of the render's output finishing
equal their torch definitions (float64 references), values and gradients, including the clamped cases."""

from __future__ import annotations

import pytest
import torch

from go_core.coarse.losses import l1, mask_bce, photometric_terms, ssim
from go_core.render.api import DEPTH_EPS
from go_core.render.cpu import finish_cpu


def _images(h=37, w=53, seed=0):
    g = torch.Generator().manual_seed(seed)
    pred, target = torch.rand(h, w, 3, generator=g), torch.rand(h, w, 3, generator=g)
    pred[:4, :4] = target[:4, :4]  # |x - y| = 0: the L1 subgradient is 0 there (torch's sgn)
    alpha = torch.rand(h, w, generator=g)
    alpha[0, :6] = 0.0  # clamped to eps: no BCE gradient
    alpha[1, :6] = 1.0  # clamped to 1 - eps
    mask = (torch.rand(h, w, generator=g) > 0.5).float()
    mask[3] = 0.3  # fractional coverage
    return pred, target, alpha, mask


@pytest.mark.parametrize("with_bce", [True, False])
def test_photometric_terms_match_the_float64_definitions(with_bce):
    pred, target, alpha, mask = _images()
    x = pred.clone().requires_grad_()
    a = alpha.clone().requires_grad_()
    l1v, s, b = photometric_terms(x, target, a if with_bce else None, mask if with_bce else None)
    assert (b is None) == (not with_bce)
    total = 0.3 * l1v + 0.7 * (1.0 - s) + (0.05 * b if with_bce else 0.0)
    total.backward()

    x64, a64 = pred.double().requires_grad_(), alpha.double().requires_grad_()
    t64 = target.double()
    ref_l1, ref_s = l1(x64, t64), ssim(x64, t64)
    ref = 0.3 * ref_l1 + 0.7 * (1.0 - ref_s)
    if with_bce:
        # the clamp bounds are float32 (as for a float32 alpha in mask_bce): value compared to float32 torch
        ref_b = mask_bce(a64, mask.double())
        ref = ref + 0.05 * ref_b
        assert float(b.detach()) == pytest.approx(float(mask_bce(alpha, mask)), rel=1e-6)
    ref.backward()
    assert float(l1v.detach()) == pytest.approx(float(ref_l1.detach()), rel=1e-6)
    assert float(s.detach()) == pytest.approx(float(ref_s.detach()), abs=1e-7)
    torch.testing.assert_close(x.grad.double(), x64.grad, rtol=1e-5, atol=1e-9)
    assert (x.grad[:4, :4] != 0).all()  # SSIM still pulls where the L1 term has zero subgradient
    if with_bce:
        # gradients where the float32 and float64 clamps agree (not the 1 - eps row)
        torch.testing.assert_close(a.grad[2:].double(), a64.grad[2:], rtol=1e-5, atol=1e-9)
        assert (a.grad[:2, :6] == 0).all()
    else:
        assert a.grad is None


def test_photometric_terms_fall_back_to_torch_for_other_inputs():
    pred, target, alpha, mask = _images(h=20, w=24)
    alpha = alpha.clamp(0.01, 0.99)  # away from the clamp bounds, which differ between float32 and float64
    fast = photometric_terms(pred, target, alpha, mask)
    slow = photometric_terms(pred.double(), target.double(), alpha.double(), mask.double())
    for f, s in zip(fast, slow, strict=True):
        assert s.dtype == torch.float64
        assert float(f) == pytest.approx(float(s), rel=1e-5)
    with pytest.raises(ValueError, match="both alpha and mask"):
        photometric_terms(pred, target, alpha, None)


@pytest.mark.parametrize("bg_shape", ["per_camera", "shared", "none"])
@pytest.mark.parametrize("used", [(1, 1, 1), (1, 0, 0), (0, 1, 1)])
def test_finish_matches_the_torch_compositing(bg_shape, used):
    g = torch.Generator().manual_seed(1)
    C, H, W = 2, 19, 23
    acc = torch.rand(C, H, W, 4, generator=g)
    alpha = torch.rand(C, H, W, 1, generator=g)
    alpha[0, 0, :4] = 0.0  # empty pixels: depth clamps to acc/eps, no alpha gradient through the depth
    alpha[1, 2, :3] = 1e-12
    bg = {"per_camera": torch.rand(C, 3, generator=g), "shared": torch.rand(3, generator=g), "none": None}[
        bg_shape
    ]
    wr, wd, wa = (torch.randn(C, H, W, k, generator=g) for k in (3, 1, 1))

    f, a = acc.clone().requires_grad_(), alpha.clone().requires_grad_()
    rgb, depth, al = finish_cpu(f, a, bg, DEPTH_EPS)
    terms = [(rgb * wr).sum(), (depth * wd).sum(), (al * wa).sum()]
    sum(t for t, u in zip(terms, used, strict=True) if u).backward()

    f64, a64 = acc.double().requires_grad_(), alpha.double().requires_grad_()
    rgb64 = f64[..., :3] + ((1.0 - a64) * bg.double().reshape(-1, 1, 1, 3) if bg is not None else 0.0)
    depth64 = f64[..., 3:4] / torch.clamp_min(a64, DEPTH_EPS)
    terms64 = [(rgb64 * wr).sum(), (depth64 * wd).sum(), (a64 * wa).sum()]
    sum(t for t, u in zip(terms64, used, strict=True) if u).backward()

    torch.testing.assert_close(rgb.double(), rgb64, rtol=1e-6, atol=1e-7)
    torch.testing.assert_close(depth.double(), depth64, rtol=1e-6, atol=0.0)
    assert torch.equal(al, alpha)
    torch.testing.assert_close(f.grad.double(), f64.grad, rtol=1e-6, atol=1e-7)
    ref_a = a64.grad if a64.grad is not None else torch.zeros_like(a64)  # alpha unused: zeros, not None
    torch.testing.assert_close(a.grad.double(), ref_a, rtol=1e-5, atol=1e-6)


def _bce64(alpha: torch.Tensor, mask: torch.Tensor, lo: float, hi: float) -> float:
    a = alpha.double().clamp(lo, hi)
    m = mask.double()
    return float(-(m * a.log() + (1.0 - m) * torch.log1p(-a)).mean())


@pytest.mark.parametrize("w", [16, 37])
def test_bce_value_is_float_accurate_where_naive_float32_is_not(w):
    """The BCE value on alphas whose log(1 - a) a plain float32 log gets wrong by up to ~6% (a ~ 1e-6: 1 - a
    rounds), near 1 and at both clamp bounds, a row width that is not a multiple of the 16-lane vectors:
    float64 reference to 2e-6 relative (a float32 log(1 - a) is off by more than 1e-5 here)."""
    g = torch.Generator().manual_seed(3)
    h = 9
    pred, target = torch.rand(h, w, 3, generator=g), torch.rand(h, w, 3, generator=g)
    alpha = 10 ** (-6.0 + 2.0 * torch.rand(h, w, generator=g))  # 1e-6 .. 1e-4
    mask = torch.zeros(h, w)
    alpha[0] = 1.0 - alpha[0]  # near 1, under a mask of 1
    mask[0] = 1.0
    alpha[1, :5] = 0.0  # clamped to eps
    alpha[1, 5:10] = 1.0  # clamped to 1 - eps, under a mask of 1
    mask[1, 5:10] = 1.0
    _, _, b = photometric_terms(pred, target, alpha, mask)
    lo = float(torch.tensor(1e-6, dtype=torch.float32))
    hi = float(torch.tensor(1.0 - 1e-6, dtype=torch.float32))
    ref = _bce64(alpha, mask, lo, hi)
    assert float(b) == pytest.approx(ref, rel=2e-6)
    naive = float(-(mask * alpha.clamp(lo, hi).log() + (1 - mask) * (1 - alpha.clamp(lo, hi)).log()).mean())
    assert abs(naive - ref) > 1e-5 * abs(ref)  # the case is hard: a float32 log(1 - a) fails it


def test_bce_value_propagates_nan_and_reaches_inf_without_clamp():
    pred, target, alpha, mask = _images(h=5, w=20)
    alpha = alpha.clamp(0.01, 0.99)
    alpha[2, 17] = float("nan")
    _, _, b = photometric_terms(pred, target, alpha, mask)
    assert torch.isnan(b)
    alpha[2, 17] = 0.0  # log(0) under a mask of 1, no clamp: +inf (torch's lerp form gives NaN)
    mask[2, 17] = 1.0
    _, _, b = photometric_terms(pred, target, alpha, mask, eps=0.0)
    assert torch.isinf(b) and b > 0
