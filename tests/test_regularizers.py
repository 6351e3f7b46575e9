"""Sparse-view regularisers (go_core/coarse/regularizers.py) against references, and the coarse budget
knob."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from go_core.camera import look_at
from go_core.coarse.loop import CoarseConfig, optimize
from go_core.coarse.regularizers import (
    RegularizerConfig,
    anisotropy_loss,
    drop_compensation,
    drop_rate,
    opacity_decay_loss,
    opacity_entropy_loss,
    outside_alpha_loss,
    regularization_loss,
)
from go_core.gaussians import Gaussians
from go_core.render import render

pytestmark = pytest.mark.usefixtures("single_thread")


# DropGaussian ----------------------------------------------------------------------------------------------
def test_drop_rate_rises_linearly_to_gamma_and_is_off_at_zero():
    T, gamma = 1000, 0.2
    rates = [drop_rate(t, T, gamma) for t in range(0, T + 1)]
    assert rates[0] == 0.0 and rates[-1] == pytest.approx(gamma)
    assert rates[500] == pytest.approx(0.1) and rates[250] == pytest.approx(0.05)
    assert np.allclose(np.diff(rates), gamma / T)  # linear: r_t = γ t / T
    assert drop_rate(2 * T, T, gamma) == pytest.approx(gamma)  # never above γ
    assert drop_rate(500, T, 0.0) == 0.0


def test_drop_compensation_values_and_unbiasedness():
    gen = torch.Generator().manual_seed(3)
    assert drop_compensation(10, 0.0, gen) is None  # off: no draw from the generator
    assert torch.equal(gen.get_state(), torch.Generator().manual_seed(3).get_state())
    rate, n, draws = 0.3, 200, 4000
    m = torch.stack([drop_compensation(n, rate, gen) for _ in range(draws)])  # [draws, n]
    assert torch.unique(m).tolist() == pytest.approx([0.0, 1.0 / (1.0 - rate)])
    # each Gaussian: E[M] = 1; the std of a mean over `draws` Bernoulli factors is sqrt(r/(1-r)/draws)
    sd = math.sqrt(rate / (1 - rate) / draws)
    assert torch.all((m.mean(0) - 1.0).abs() < 5 * sd)
    assert abs(float((m == 0).float().mean()) - rate) < 0.005  # drop share = rate
    with pytest.raises(ValueError):
        drop_compensation(3, 1.0, gen)


def _single_gaussian_render(opacity_scale: float) -> torch.Tensor:
    size = 16
    K = np.array([[20.0, 0, size / 2], [0, 20.0, size / 2], [0, 0, 1]])
    cam = look_at("c", np.array([0, 0, 3.0]), np.zeros(3), np.array([0, 1.0, 0]), K, size, size)
    o = torch.tensor([0.3]) * opacity_scale
    out = render(
        torch.zeros(1, 3),
        torch.tensor([[1.0, 0, 0, 0]]),
        torch.full((1, 3), 0.2),
        o,
        torch.tensor([[0.8, 0.4, 0.2]]),
        cam.viewmat_tensor()[None],
        cam.K_tensor()[None],
        size,
        size,
        backend="cpu",
    )
    return out.alpha[0, ..., 0]


def test_dropped_renders_average_to_the_test_time_render():
    """Unbiased at test time: with one Gaussian (alpha linear in opacity below the 0.99 clamp), the mean of
    the training renders over the drop distribution equals the render without dropping (on the pixels
    where the Gaussian passes the rasterizer's 1/255 alpha cut-off, a threshold, not a linear map)."""
    rate = 0.25
    kept = _single_gaussian_render(1.0 / (1.0 - rate))
    expected = (1.0 - rate) * kept + rate * _single_gaussian_render(0.0)
    test_time = _single_gaussian_render(1.0)
    reached = test_time >= 1.0 / 255.0
    assert int(reached.sum()) > 20 and float(test_time.max()) > 0.1
    assert torch.allclose(expected[reached], test_time[reached], rtol=1e-5, atol=1e-7)


# Loss terms: values against float64 references, gradients against finite differences ----------------------
def test_outside_alpha_value_and_gradient():
    g = torch.Generator().manual_seed(0)
    alpha = torch.rand(7, 9, generator=g, dtype=torch.float64, requires_grad=True)
    mask = (torch.rand(7, 9, generator=g, dtype=torch.float64) > 0.5).double()
    mask[0, 0] = 0.3  # fractional mask pixel
    a, m = alpha.detach().numpy(), mask.numpy()
    ref = float(((1 - m) * a**2).sum() / (1 - m).sum())
    assert float(outside_alpha_loss(alpha.detach(), mask)) == pytest.approx(ref, rel=1e-12)
    assert torch.autograd.gradcheck(lambda x: outside_alpha_loss(x, mask), (alpha,))
    # the renderer's [1,H,W,1] alpha against an [H,W] mask; a full mask gives 0
    assert float(outside_alpha_loss(alpha.detach()[None, ..., None], mask)) == pytest.approx(ref, rel=1e-12)
    assert float(outside_alpha_loss(alpha.detach(), torch.ones_like(mask))) == 0.0


def test_anisotropy_value_and_gradient():
    g = torch.Generator().manual_seed(1)
    ls = (torch.randn(20, 3, generator=g, dtype=torch.float64) * 1.5).requires_grad_()
    s = np.exp(ls.detach().numpy())
    ref = float(np.maximum(s.max(1) / s.min(1) - 4.0, 0).mean())
    assert ref > 0 and float(anisotropy_loss(ls.detach(), 4.0)) == pytest.approx(ref, rel=1e-12)
    # finite differences away from the hinge and from ties between axes
    ratio = s.max(1) / s.min(1)
    sel = torch.from_numpy(np.abs(ratio - 4.0) > 0.05)
    assert torch.autograd.gradcheck(lambda x: anisotropy_loss(x, 4.0), (ls[sel].detach().requires_grad_(),))
    assert float(anisotropy_loss(torch.zeros(5, 3), 4.0)) == 0.0  # isotropic: no penalty


def test_opacity_decay_value_and_gradient():
    logits = torch.linspace(-3, 3, 11, dtype=torch.float64, requires_grad=True)
    ref = float(np.mean(1 / (1 + np.exp(-logits.detach().numpy()))))
    assert float(opacity_decay_loss(logits.detach())) == pytest.approx(ref, rel=1e-12)
    assert torch.autograd.gradcheck(opacity_decay_loss, (logits,))


def test_opacity_entropy_value_and_gradient():
    logits = torch.tensor([0.0, 2.0, -3.0, 8.0], dtype=torch.float64, requires_grad=True)
    p = torch.sigmoid(logits).detach()
    want = float((-(p * p.log() + (1 - p) * (1 - p).log())).mean())
    assert opacity_entropy_loss(logits).item() == pytest.approx(want, rel=1e-12)
    assert opacity_entropy_loss(torch.zeros(3)).item() == pytest.approx(math.log(2))  # the maximum
    assert torch.autograd.gradcheck(opacity_entropy_loss, (logits,))
    g = opacity_entropy_loss(logits)
    (grad,) = torch.autograd.grad(g, logits)
    assert grad[1] < 0 < grad[2]  # opaque ones are pushed up, faint ones down; 0.5 is stationary
    assert grad[0] == pytest.approx(0.0, abs=1e-12)


def test_regularization_loss_sums_the_enabled_terms():
    g = Gaussians.from_points(torch.randn(6, 3), torch.rand(6, 3), torch.full((6,), 0.1), 0.5, 0)
    g.log_scales[:, 0] += 3.0
    alpha, mask = torch.rand(4, 4), (torch.rand(4, 4) > 0.5).float()
    off = RegularizerConfig(lambda_opacity=0.0, lambda_anisotropy=0.0)  # both on by default
    assert regularization_loss(off, g, alpha, mask, 1.0) == (None, {})
    cfg = RegularizerConfig(lambda_outside=2.0, lambda_anisotropy=0.5, max_anisotropy=3.0, lambda_opacity=0.1)
    total, parts = regularization_loss(cfg, g, alpha, mask, 1.0)
    want = (
        2.0 * outside_alpha_loss(alpha, mask)
        + 0.5 * anisotropy_loss(g.log_scales, 3.0)
        + 0.1 * opacity_decay_loss(g.opacity_logits)
    )
    assert float(total) == pytest.approx(float(want), rel=1e-6)
    assert set(parts) == {"outside_alpha", "anisotropy", "opacity"}
    total, parts = regularization_loss(cfg, g, alpha, None, 1.0)  # no mask: no silhouette term
    assert "outside_alpha" not in parts


# In the loop -----------------------------------------------------------------------------------------------
def _tiny_problem():
    from tests.test_training import _init, _tiny_config, _views

    return _init(), _views(), _tiny_config


def test_loop_with_every_regulariser_is_deterministic_and_logs_the_terms():
    init, views, tiny_config = _tiny_problem()
    cfg = replace(
        tiny_config(30),
        drop_gamma=0.3,
        lambda_outside=0.1,
        lambda_anisotropy=0.01,
        lambda_opacity=0.01,
        lambda_opacity_entropy=0.01,
    )
    a, sa = optimize(init, views, cfg, generator=torch.Generator().manual_seed(5))
    b, sb = optimize(init, views, cfg, generator=torch.Generator().manual_seed(5))
    for name, t in a.tensors().items():
        assert torch.equal(getattr(b, name), t), name
    assert {"outside_alpha", "anisotropy", "opacity", "opacity_entropy"} <= set(sa.loss_log[-1])
    plain = tiny_config(30)
    c, _ = optimize(init, views, plain, generator=torch.Generator().manual_seed(5))
    assert not torch.equal(c.means, a.means)  # the regularisers change the trajectory
    # round trip through the stored config (coarse.json -> leave-one-out runs)
    assert CoarseConfig.from_dict(cfg.to_dict()) == cfg


def test_regularisers_off_leave_the_run_bit_identical():
    init, views, tiny_config = _tiny_problem()
    a, _ = optimize(init, views, tiny_config(20), generator=torch.Generator().manual_seed(2))
    cfg = replace(tiny_config(20), drop_gamma=0.0, max_anisotropy=3.0)
    b, _ = optimize(init, views, cfg, generator=torch.Generator().manual_seed(2))
    for name, t in a.tensors().items():
        assert torch.equal(getattr(b, name), t), name


# The budget knob -------------------------------------------------------------------------------------------
PAPER = {
    "iterations": 10_000,
    "schedule_iterations": 10_000,
    "opacity_reset_min_interval": 500,
    "sh_increase_every": 1000,
    "position_lr_max_steps": 30_000,
    "densify_from": 500,
    "densify_until": 6000,
    "densify_every": 100,
    "opacity_reset_every": 1000,
    "floater_every": 500,
    "floater_from": 500,
    "floater_until": 6000,
}


def scale_schedule(values: dict) -> dict:
    config = CoarseConfig.from_dict(values).scaled_schedule()
    return {k: getattr(config, k) for k in values}


def test_budget_scales_every_schedule():
    assert scale_schedule(PAPER) == PAPER  # the paper's length: exactly the paper's settings
    short = scale_schedule({**PAPER, "iterations": 1000})
    assert short == {
        **PAPER,
        "iterations": 1000,
        "sh_increase_every": 100,
        "position_lr_max_steps": 3000,
        "densify_from": 50,
        "densify_until": 600,
        "densify_every": 10,
        "opacity_reset_every": 0,  # a 100-iteration reset period is below the 500 minimum: off
        "floater_every": 50,
        "floater_from": 50,
        "floater_until": 600,
    }
    assert scale_schedule({**PAPER, "iterations": 5000})["opacity_reset_every"] == 500
    assert scale_schedule({**PAPER, "iterations": 20})["densify_every"] == 1  # intervals stay >= 1
    as_written = {**PAPER, "iterations": 1000, "schedule_iterations": 0}
    assert scale_schedule(as_written) == as_written
    # params left out take the CoarseConfig (paper) defaults, scaled too
    cfg = CoarseConfig.from_dict({"iterations": 2000, "schedule_iterations": 10_000}).scaled_schedule()
    assert (cfg.densify_from, cfg.densify_until, cfg.floater_every) == (100, 1200, 100)
    assert cfg.sh_increase_every == 200 and cfg.position_lr_max_steps == 6000


def test_regulariser_params_map_to_the_config():
    cfg = CoarseConfig.from_dict(
        {"drop_gamma": 0.2, "lambda_outside": 0.1, "lambda_anisotropy": 0.01, "max_anisotropy": 8,
         "lambda_opacity": 0.001}
    )  # fmt: skip
    assert (
        isinstance(cfg, RegularizerConfig)
        and cfg.max_anisotropy == 8.0
        and isinstance(cfg.max_anisotropy, float)
    )
    assert (cfg.drop_gamma, cfg.lambda_outside, cfg.lambda_anisotropy, cfg.lambda_opacity) == (
        0.2,
        0.1,
        0.01,
        0.001,
    )
