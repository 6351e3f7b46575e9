"""Loss terms: SSIM against scikit-image and finite differences; depth normalisation invariances."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from go_core.coarse.losses import depth_loss, dssim, l1, mask_bce, normalize_depth, ssim, ssim_map

pytestmark = pytest.mark.usefixtures("single_thread")  # small tensors: one thread is faster


def _pair(h=40, w=50, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    a = torch.rand(h, w, 3, generator=g, dtype=dtype)
    b = (a + 0.2 * torch.rand(h, w, 3, generator=g, dtype=dtype) - 0.1).clamp(0, 1)
    return a, b


def test_ssim_matches_scikit_image_on_valid_window_region():
    a, b = _pair()
    ref = structural_similarity(
        a.numpy(),
        b.numpy(),
        channel_axis=2,
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        data_range=1.0,
    )
    ours = ssim_map(a, b)[..., 5:-5, 5:-5].mean().item()
    assert ours == pytest.approx(ref, abs=1e-10)


def test_ssim_layouts_agree_and_identity_is_one():
    a, b = _pair()
    hwc = ssim(a, b).item()
    bchw = ssim(a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None]).item()
    bhwc = ssim(a[None], b[None], channels_last=True).item()
    assert hwc == pytest.approx(bchw, abs=1e-12) and hwc == pytest.approx(bhwc, abs=1e-12)
    assert ssim(a, a).item() == pytest.approx(1.0, abs=1e-12)
    assert dssim(a, a).item() == pytest.approx(0.0, abs=1e-12)


def test_ssim_gradient_matches_finite_differences():
    a, b = _pair(12, 13, seed=1)
    a = a.permute(2, 0, 1)[None].clone().requires_grad_(True)
    b = b.permute(2, 0, 1)[None]
    assert torch.autograd.gradcheck(lambda x: ssim(x, b), (a,), eps=1e-6, atol=1e-7)


def test_l1_weighted_and_mask_bce_known_values():
    p = torch.tensor([0.0, 1.0, 0.5])
    t = torch.tensor([1.0, 1.0, 0.0])
    assert l1(p, t).item() == pytest.approx(0.5)
    assert l1(p, t, torch.tensor([1.0, 0.0, 1.0])).item() == pytest.approx(0.75)
    alpha = torch.tensor([[0.25, 0.75]])[..., None]  # [1,2,1] like the renderer's alpha
    mask = torch.tensor([[0.0, 1.0]])
    expected = -(np.log(0.75) + np.log(0.75)) / 2
    assert mask_bce(alpha, mask).item() == pytest.approx(expected, rel=1e-6)
    assert np.isfinite(mask_bce(torch.tensor([0.0, 1.0]), torch.tensor([1.0, 0.0])).item())


@pytest.mark.parametrize("scale,shift", [(3.0, 5.0), (0.01, -2.0), (250.0, 1e3)])
def test_depth_normalisation_is_shift_and_scale_invariant(scale, shift):
    g = torch.Generator().manual_seed(2)
    d = torch.rand(30, 40, generator=g, dtype=torch.float64) * 4 + 1
    valid = torch.rand(30, 40, generator=g) > 0.3
    n1 = normalize_depth(d, valid)
    n2 = normalize_depth(scale * d + shift, valid)
    assert torch.allclose(n1[valid], n2[valid], atol=1e-9)
    # median 0 and mean absolute deviation 1 over the valid pixels
    assert n1[valid].median().abs().item() < 1e-9  # torch's median is an element (the lower one)
    assert n1[valid].abs().mean().item() == pytest.approx(1.0, rel=1e-6)
    prior = 0.5 * d + 7.0
    assert depth_loss(scale * d + shift, prior, valid).item() == pytest.approx(0.0, abs=1e-8)
    assert depth_loss(-d, prior, valid).item() > 0.5  # reversed order is penalised


def test_depth_loss_is_differentiable_and_ignores_invalid_pixels():
    g = torch.Generator().manual_seed(3)
    d = (torch.rand(16, 16, generator=g, dtype=torch.float64) + 1).requires_grad_(True)
    prior = torch.rand(16, 16, generator=g, dtype=torch.float64)
    valid = torch.zeros(16, 16, dtype=torch.bool)
    valid[4:12, 4:12] = True
    loss = depth_loss(d, prior, valid)
    loss.backward()
    assert d.grad[~valid].abs().max().item() == 0.0
    assert d.grad[valid].abs().max().item() > 0.0
    empty = depth_loss(d, prior, torch.zeros_like(valid))
    assert empty.item() == 0.0
