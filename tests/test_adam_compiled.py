"""GaussianOptimizer's compiled Adam step (all six tensors in one parallel region) is torch.optim.Adam's
update: same parameters and moments as a float64 torch Adam over several steps with per-group learning
rates, a group that gets no gradient, and a prune in between; the state keeps torch's layout."""

from __future__ import annotations

import torch

from go_core.coarse.optim import PARAM_NAMES, GaussianOptimizer, LearningRates
from go_core.gaussians import Gaussians


def _gaussians(n: int, seed: int) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    quats = torch.randn(n, 4, generator=g)
    return Gaussians(
        torch.randn(n, 3, generator=g),
        quats / quats.norm(dim=1, keepdim=True),
        torch.randn(n, 3, generator=g) * 0.1 - 3.0,
        torch.randn(n, generator=g),
        torch.randn(n, 9, 3, generator=g) * 0.2,
    )


def _reference(opt: GaussianOptimizer) -> tuple[dict, torch.optim.Adam]:
    """A float64 torch Adam with the same groups (learning rates, eps) as ``opt``."""
    params = {k: torch.nn.Parameter(v.detach().double().clone()) for k, v in opt.params.items()}
    groups = [
        {"params": [params[g["name"]]], "lr": g["lr"], "name": g["name"]} for g in opt.optimizer.param_groups
    ]
    return params, torch.optim.Adam(groups, eps=opt.optimizer.param_groups[0]["eps"])


def test_compiled_adam_matches_torch_adam(monkeypatch):
    opt = GaussianOptimizer(_gaussians(5000, 0), LearningRates(), extent=2.5)

    def not_this_path():
        raise AssertionError("torch's Adam ran: the compiled step did not apply")

    monkeypatch.setattr(opt.optimizer, "step", not_this_path)
    ref_params, ref = _reference(opt)
    g = torch.Generator().manual_seed(1)
    for step in range(1, 13):
        if step == 7:  # a prune: both keep the surviving rows' moments
            keep = torch.rand(len(opt), generator=g) > 0.3
            opt.keep(keep)
            for name in PARAM_NAMES:
                old = ref_params[name]
                new = torch.nn.Parameter(old.detach()[keep].clone())
                st = ref.state.pop(old)
                ref.state[new] = {k: v if k == "step" else v[keep].clone() for k, v in st.items()}
                for group in ref.param_groups:
                    if group["params"][0] is old:
                        group["params"][0] = new
                ref_params[name] = new
        for name in PARAM_NAMES:
            if name == "shN" and step % 4 == 0:  # no gradient this step: not updated, its step count stays
                continue
            grad = torch.randn(opt.params[name].shape, generator=g) * 10.0 ** float(
                torch.randint(-4, 1, (1,))
            )
            opt.params[name].grad = grad.clone()
            ref_params[name].grad = grad.double()
        opt.step()
        ref.step()
        ref.zero_grad(set_to_none=True)
        for name in PARAM_NAMES:
            torch.testing.assert_close(
                opt.params[name].detach().double(), ref_params[name].detach(), rtol=1e-5, atol=5e-6
            )  # float32 rounding: torch's own fused float32 Adam is off by up to 1.1e-6 here; lr >= 1.25e-4
            assert opt.params[name].grad is None
    for name in PARAM_NAMES:
        ours, theirs = opt.optimizer.state[opt.params[name]], ref.state[ref_params[name]]
        assert ours["step"].dtype == torch.float32 and ours["step"].dim() == 0
        assert float(ours["step"]) == float(theirs["step"]) == (9 if name == "shN" else 12)
        for key in (
            "exp_avg",
            "exp_avg_sq",
        ):  # float32 sums of gradients from 1e-4 to 1: relative to the largest
            scale = float(theirs[key].abs().max())
            torch.testing.assert_close(ours[key].double(), theirs[key], rtol=1e-5, atol=1e-6 * scale)
