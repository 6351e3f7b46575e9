"""Issue 33 (real captures): the inside-mask alpha term, the per-view colour correction and the
object-relative screen-size limit that keeps real/ethiopian_head from collapsing."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from go_core.coarse.color_correction import ViewColorCorrection
from go_core.coarse.densify import DensifyConfig, DensifyStrategy, screen_size_limit
from go_core.coarse.regularizers import RegularizerConfig, eroded_mask, inside_alpha_loss, regularization_loss

pytestmark = pytest.mark.usefixtures("single_thread")


# Inside-mask alpha ----------------------------------------------------------------------------------------
def test_eroded_mask_keeps_pixels_whose_square_is_inside():
    mask = torch.zeros(12, 14)
    mask[2:10, 3:12] = 1.0  # an 8 x 9 rectangle
    ref = np.zeros((12, 14))
    ref[4:8, 5:10] = 1.0  # radius 2: 2 px off every side
    assert torch.equal(eroded_mask(mask, 2), torch.from_numpy(ref).float())
    assert torch.equal(eroded_mask(mask, 0), mask)
    assert float(eroded_mask(mask, 5).sum()) == 0.0  # thinner than the band: nothing left


def test_inside_alpha_value_and_gradient_against_finite_differences():
    g = torch.Generator().manual_seed(0)
    alpha = torch.rand(9, 11, generator=g, dtype=torch.float64)
    interior = (torch.rand(9, 11, generator=g, dtype=torch.float64) > 0.4).double()
    a, w = alpha.numpy(), interior.numpy()
    ref = float((w * (1 - a) ** 2).sum() / w.sum())
    assert float(inside_alpha_loss(alpha, interior)) == pytest.approx(ref, rel=1e-12)
    # analytic gradient -2 w (1 - a) / sum w, and central finite differences of the float64 value
    x = alpha.clone().requires_grad_()
    inside_alpha_loss(x, interior).backward()
    assert np.allclose(x.grad.numpy(), -2 * w * (1 - a) / w.sum(), rtol=1e-12, atol=0)
    h, fd = 1e-6, np.zeros_like(a)
    for idx in np.ndindex(a.shape):
        up, dn = alpha.clone(), alpha.clone()
        up[idx] += h
        dn[idx] -= h
        fd[idx] = (float(inside_alpha_loss(up, interior)) - float(inside_alpha_loss(dn, interior))) / (2 * h)
    assert np.allclose(x.grad.numpy(), fd, rtol=1e-6, atol=1e-9)
    # the renderer's [1,H,W,1] alpha; an opaque interior or an empty one gives 0
    assert float(inside_alpha_loss(alpha[None, ..., None], interior)) == pytest.approx(ref, rel=1e-12)
    assert float(inside_alpha_loss(torch.ones_like(alpha), interior)) == 0.0
    assert float(inside_alpha_loss(alpha, torch.zeros_like(interior))) == 0.0


def test_inside_term_in_the_regulariser_sum_uses_the_eroded_mask():
    from go_core.gaussians import Gaussians

    g = Gaussians.from_points(torch.randn(4, 3), torch.rand(4, 3), torch.full((4,), 0.1), 0.5, 0)
    alpha = torch.rand(10, 10, generator=torch.Generator().manual_seed(1))
    mask = torch.zeros(10, 10)
    mask[1:9, 1:9] = 1.0
    cfg = RegularizerConfig(lambda_opacity=0.0, lambda_anisotropy=0.0, lambda_inside=0.5, inside_erode_px=1)
    total, parts = regularization_loss(cfg, g, alpha, mask, 1.0)
    want = 0.5 * inside_alpha_loss(alpha, eroded_mask(mask, 1))
    assert set(parts) == {"inside_alpha"} and float(total) == pytest.approx(float(want), rel=1e-6)
    assert regularization_loss(cfg, g, alpha, None, 1.0) == (None, {})  # no mask: no term


# Colour correction ----------------------------------------------------------------------------------------
def _render_like(seed: int, h: int = 6, w: int = 5):
    g = torch.Generator().manual_seed(seed)
    alpha = torch.rand(h, w, generator=g)
    fg = torch.rand(h, w, 3, generator=g) * alpha[..., None]
    bg = torch.rand(3, generator=g)
    return fg + (1 - alpha[..., None]) * bg, alpha, bg


def test_color_correction_is_the_identity_at_init_and_for_test_views():
    cc = ViewColorCorrection(4, lr=0.01)
    rgb, alpha, bg = _render_like(0)
    for v in range(4):
        assert torch.allclose(cc.apply(v, rgb, alpha, bg), rgb, atol=1e-7)
    assert cc.apply(None, rgb, alpha, bg) is rgb  # a test view: not corrected
    mat, bias = cc.transforms()
    assert torch.equal(mat, torch.eye(3).expand(4, 3, 3)) and torch.equal(bias, torch.zeros(4, 3))


def test_color_correction_learns_one_views_exposure_and_keeps_the_mean_identity():
    cc = ViewColorCorrection(3, lr=0.02)
    rgb, alpha, bg = _render_like(1, 16, 16)
    fg = rgb - (1 - alpha[..., None]) * bg
    gain = torch.tensor([1.3, 1.1, 0.8])
    targets = [rgb, rgb, fg * gain + (1 - alpha[..., None]) * bg]  # view 2 shot with another exposure
    colour = torch.ones(3, requires_grad=True)  # the model's colours (a gain on its foreground), learnt too
    model_opt = torch.optim.Adam([colour], lr=0.02)
    for _ in range(1500):
        render = fg * colour + (1 - alpha[..., None]) * bg
        loss = sum(((cc.apply(v, render, alpha, bg) - t) ** 2).mean() for v, t in enumerate(targets))
        loss.backward()
        cc.step()
        model_opt.step()
        model_opt.zero_grad()
    mat, bias = cc.transforms()
    assert torch.allclose(mat.mean(0), torch.eye(3), atol=1e-6)  # the gauge: mean transform = identity
    assert torch.allclose(bias.mean(0), torch.zeros(3), atol=1e-6)
    # view 2 relative to the others carries the exposure change; the background is never corrected
    rel = torch.linalg.solve(mat[0], mat[2])
    assert torch.allclose(torch.diagonal(rel), gain, atol=0.01)
    # the model times view 0's transform reproduces view 0's photo (the rest is in the model colours)
    assert torch.allclose(colour.detach() * torch.diagonal(mat[0]).detach(), torch.ones(3), atol=0.01)
    empty = torch.zeros_like(alpha)
    assert torch.allclose(cc.apply(2, bg.expand_as(rgb), empty, bg), bg.expand_as(rgb), atol=1e-6)
    state = cc.state_dict()
    other = ViewColorCorrection(3, lr=0.02)
    other.load_state_dict(state)
    assert torch.equal(other.transforms()[0], mat)


# Collapse guard: the screen-size prune relative to the object -------------------------------------------
def _strategy_after_interval(radius_scale: float, mask_side: int, fraction: float) -> torch.Tensor:
    """The prune mask of a strategy that saw these max radii (px, × radius_scale) over one interval, with a
    square training mask of side ``mask_side`` px (the same object imaged at another resolution)."""
    cfg = DensifyConfig(opacity_reset_every=10, max_screen_size=20.0, max_screen_fraction=fraction)
    mask = np.zeros((2 * mask_side, 2 * mask_side), np.float32)
    mask[:mask_side, :mask_side] = 1.0
    n = 6
    strat = DensifyStrategy(cfg, 1.0, n, screen_size_limit(cfg, [mask, mask]))
    strat.max_radii = torch.tensor([4.0, 10.0, 14.0, 18.0, 22.0, 40.0]) * radius_scale
    strat.color_grad = torch.ones(n)

    class _Opt:
        params = {
            "opacity_logits": torch.zeros(n),
            "log_scales": torch.full((n, 3), -5.0),
        }

    prune, _ = strat._prune_mask(_Opt(), step=20)
    return prune


def test_screen_limit_follows_the_object_not_the_resolution():
    # the same Gaussians seen at 1x and 2x resolution: the object-relative rule prunes the same ones
    low = _strategy_after_interval(1.0, 120, 0.15)  # limit 0.15 x 120 = 18 px
    high = _strategy_after_interval(2.0, 240, 0.15)  # limit 36 px
    assert low.tolist() == [False, False, False, False, True, True]
    assert torch.equal(low, high)
    # the 3DGS pixel rule (fraction 0) prunes twice the share at 2x: the collapse of real/ethiopian_head
    px_low = _strategy_after_interval(1.0, 120, 0.0)
    px_high = _strategy_after_interval(2.0, 240, 0.0)
    assert int(px_low.sum()) == 2 and int(px_high.sum()) == 4
    assert screen_size_limit(replace(DensifyConfig(), max_screen_size=0.0), [np.ones((8, 8))]) == 0.0
    assert screen_size_limit(DensifyConfig(), [None]) == 20.0  # no mask: the pixel limit
