"""Densification strategy: clone / split / prune rules, the budget, Adam state bookkeeping, opacity reset."""

from __future__ import annotations

import math

import pytest
import torch

from go_core.coarse.densify import DensifyConfig, DensifyStrategy
from go_core.coarse.optim import GaussianOptimizer, LearningRates
from go_core.gaussians import Gaussians

pytestmark = pytest.mark.usefixtures("single_thread")  # small tensors: one thread is faster


EXTENT = 1.0


def _setup(scales, opacities, grads, colour_grads=None, **cfg):
    n = len(scales)
    g = Gaussians(
        torch.arange(n * 3, dtype=torch.float32).reshape(n, 3),
        torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        torch.log(torch.tensor(scales, dtype=torch.float32))[:, None].repeat(1, 3),
        torch.logit(torch.tensor(opacities, dtype=torch.float32)),
        torch.arange(n, dtype=torch.float32)[:, None, None].repeat(1, 9, 3),
    )
    opt = GaussianOptimizer(g, LearningRates(), EXTENT)
    # one optimiser step so every row has non-zero Adam moments
    loss = sum((p * torch.arange(1, p.numel() + 1).reshape(p.shape)).sum() for p in opt.params.values())
    loss.backward()
    opt.step()
    config = DensifyConfig(
        **{"densify_from": 0, "densify_every": 10, "opacity_reset_every": 0, "max_gaussians": 0, **cfg}
    )
    strat = DensifyStrategy(config, EXTENT, n)
    strat.grad_accum = torch.tensor(grads, dtype=torch.float32)
    strat.vis_count = torch.ones(n)
    strat.color_grad = (
        torch.ones(n) if colour_grads is None else torch.tensor(colour_grads, dtype=torch.float32)
    )
    return opt, strat


def test_clone_split_and_prune_rules():
    # 0: small + high grad → clone; 1: large + high grad → split; 2: low grad → kept; 3: transparent → pruned
    opt, strat = _setup([0.005, 0.05, 0.005, 0.005], [0.5, 0.5, 0.5, 0.001], [1e-3, 1e-3, 1e-5, 1e-5])
    means_before = opt.params["means"].detach().clone()
    scale_split = opt.params["log_scales"].detach()[1].exp()
    changed = strat.after_step(10, opt, torch.Generator().manual_seed(0))
    assert changed == {"cloned": 1, "split": 1, "pruned": 1}
    assert len(opt) == 4 - 1 - 1 + 1 + 2  # prune 3, drop split original 1, add a clone and two halves
    means = opt.params["means"].detach()
    assert torch.equal(means[0], means_before[0]) and torch.equal(means[1], means_before[2])
    assert torch.equal(means[2], means_before[0])  # the clone sits on its original
    halves = opt.params["log_scales"].detach()[3:].exp()
    assert torch.allclose(halves, (scale_split / 1.6).expand_as(halves))
    assert (means[3:] - means_before[1]).norm(dim=1).max() < 0.05 * 6  # sampled from the original Gaussian
    assert strat.counts["cloned"] == 1 and strat.counts["split"] == 1 and strat.counts["pruned"] == 1


def test_adam_moments_follow_their_rows_and_new_rows_start_at_zero():
    opt, strat = _setup([0.005, 0.005, 0.005], [0.5, 0.5, 0.001], [1e-3, 1e-5, 1e-5])
    p_before = opt.params["means"]
    m_before = opt.optimizer.state[p_before]["exp_avg"].clone()
    strat.after_step(10, opt, torch.Generator().manual_seed(0))
    m_after = opt.optimizer.state[opt.params["means"]]["exp_avg"]
    assert torch.equal(m_after[:2], m_before[:2])  # rows 0, 1 kept (2 pruned)
    assert torch.equal(m_after[2], torch.zeros(3))  # the clone of row 0 starts fresh
    # the optimiser keeps working on the new tensors
    opt.gaussians().means.sum().backward()
    opt.step()


def test_no_contribution_pruning_and_budget():
    opt, strat = _setup([0.005] * 4, [0.5] * 4, [1e-5] * 4, colour_grads=[1.0, 0.0, 1.0, 1.0])
    strat.after_step(10, opt, torch.Generator().manual_seed(0))
    assert len(opt) == 3 and strat.counts["pruned_no_contribution"] == 1
    # budget 5 with 4 small high-gradient candidates: only the highest gradient ones fit
    opt, strat = _setup([0.005] * 4, [0.5] * 4, [4e-4, 9e-4, 3e-4, 8e-4], max_gaussians=6)
    strat.after_step(10, opt, torch.Generator().manual_seed(0))
    assert len(opt) == 6 and strat.counts["budget_limited"] == 1
    means = opt.params["means"].detach()
    assert torch.equal(means[4], means[1]) and torch.equal(means[5], means[3])  # clones of rows 1 and 3


def test_opacity_reset_and_activity_window():
    opt, strat = _setup([0.005] * 3, [0.9, 0.5, 0.005], [0.0] * 3, opacity_reset_every=20, densify_until=100)
    strat.after_step(20, opt, torch.Generator().manual_seed(0))
    assert torch.sigmoid(opt.params["opacity_logits"]).max().item() <= 0.01 + 1e-6
    assert strat.counts["opacity_resets"] == 1
    before = len(opt)
    assert strat.after_step(100, opt, torch.Generator()) == {} and len(opt) == before  # stopped
    assert not math.isnan(opt.params["opacity_logits"].sum().item())


def test_state_dict_round_trip():
    opt, strat = _setup([0.005] * 3, [0.5] * 3, [1e-3, 0.0, 0.0])
    state = strat.state_dict()
    other = DensifyStrategy(strat.config, 5.0, 1)
    other.load_state_dict(state)
    assert torch.equal(other.grad_accum, strat.grad_accum) and other.extent == strat.extent
    o2 = GaussianOptimizer(opt.snapshot(), LearningRates(), 3.0)
    o2.load_state_dict(opt.state_dict())
    for k in opt.params:
        assert torch.equal(o2.params[k], opt.params[k])
        assert torch.equal(
            o2.optimizer.state[o2.params[k]]["exp_avg_sq"], opt.optimizer.state[opt.params[k]]["exp_avg_sq"]
        )
