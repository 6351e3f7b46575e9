"""The compiled projection evaluates eight Gaussians per vector: each Gaussian's result must not depend on
its neighbours in the vector, on its position in it, or on how many Gaussians the last vector holds."""

from __future__ import annotations

import pytest
import torch

from go_core.render.projection import project_gaussians


@pytest.fixture(scope="module")
def cpu_ext():
    from go_core.render.build import load_extension

    return load_extension()


W, H = 64, 48


def _cameras() -> tuple[torch.Tensor, torch.Tensor]:
    vm = torch.eye(4)[None].repeat(2, 1, 1)
    vm[0, 2, 3] = 4.0
    c, s = torch.cos(torch.tensor(0.7)), torch.sin(torch.tensor(0.7))
    vm[1, :3, :3] = torch.tensor([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    vm[1, :3, 3] = torch.tensor([0.3, -0.2, 5.0])
    K = torch.tensor([[60.0, 0, 31.0], [0, 58.0, 25.0], [0, 0, 1]])[None].repeat(2, 1, 1)
    return vm, K


def _mixed_gaussians(n: int = 29) -> list[torch.Tensor]:
    """n Gaussians (not a multiple of 8) with hard ones spread over the vectors."""
    g = torch.Generator().manual_seed(3)
    means = torch.randn(n, 3, generator=g)
    quats = torch.randn(n, 4, generator=g)
    scales = torch.rand(n, 3, generator=g) * 0.3 + 0.01
    opac = torch.rand(n, generator=g)
    sh = torch.randn(n, 16, 3, generator=g) * 0.3
    means[2, 2] = -9.0  # behind the first camera
    means[5, 0] = float("nan")
    means[9, 1] = float("inf")
    scales[12] = 1e9  # projected extent beyond the culling limit
    quats[14] = 0.0  # zero quaternion: identity rotation
    means[17] = torch.tensor([40.0, -30.0, 1.0])  # far outside the field of view: clamped Jacobian
    scales[20] = 1e-9
    means[26, 2] = 1e-4  # in front of the camera centre, behind the near plane of camera 0
    return [means, quats, scales, opac, sh]


def _project(ext, inputs, vm, K, grads, deg, aa):
    settings = (W, H, 0.01, 1e10, 0.3, aa, deg)
    fwd = ext.project_forward(*inputs, vm, K, *settings)
    bwd = ext.project_backward(*inputs, vm, K, *settings, *grads, True)
    return list(fwd), list(bwd)


def _upstream(C: int, n: int) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(7)
    return [torch.randn(C, n, k, generator=g).squeeze(-1) for k in (2, 3, 3, 1, 1)]


def _same(a: torch.Tensor, b: torch.Tensor) -> bool:
    """Bitwise equal, NaN where the other has NaN."""
    return torch.equal(a.isnan(), b.isnan()) and torch.equal(a.nan_to_num(0.0), b.nan_to_num(0.0))


@pytest.mark.parametrize("deg,aa", [(3, True), (1, False)])
def test_each_gaussian_projects_as_if_alone(cpu_ext, deg, aa):
    vm, K = _cameras()
    inputs = _mixed_gaussians()
    n = inputs[0].shape[0]
    grads = _upstream(2, n)
    fwd, bwd = _project(cpu_ext, inputs, vm, K, grads, deg, aa)
    assert (fwd[5] == 0).any() and (fwd[5] > 0).any()  # both culled and drawn Gaussians
    for i in range(n):
        one = [t[i : i + 1].contiguous() for t in inputs]
        one_grads = [t[:, i : i + 1].contiguous() for t in grads]
        f1, b1 = _project(cpu_ext, one, vm, K, one_grads, deg, aa)
        for name, whole, alone in zip(
            ("means2d", "conics", "colors", "opac", "depth", "radii"), fwd, f1, strict=True
        ):
            assert _same(whole[:, i : i + 1], alone), (i, name)
        for name, whole, alone in zip(
            ("means", "quats", "scales", "opac", "colors"), bwd[:5], b1[:5], strict=True
        ):
            assert _same(whole[i : i + 1], alone), (i, name)
    # bands above the active degree get no gradient
    assert (bwd[4][:, (deg + 1) ** 2 :] == 0).all()
    assert (bwd[4][:, : (deg + 1) ** 2].abs() > 0).any()


def test_reordering_permutes_every_output(cpu_ext):
    vm, K = _cameras()
    inputs = _mixed_gaussians(37)
    grads = _upstream(2, 37)
    perm = torch.randperm(37, generator=torch.Generator().manual_seed(1))
    fwd, bwd = _project(cpu_ext, inputs, vm, K, grads, 2, True)
    pf, pb = _project(
        cpu_ext,
        [t[perm].contiguous() for t in inputs],
        vm,
        K,
        [t[:, perm].contiguous() for t in grads],
        2,
        True,
    )
    for whole, permuted in zip(fwd, pf, strict=True):
        assert _same(whole[:, perm], permuted)
    for whole, permuted in zip(bwd[:5], pb[:5], strict=True):
        assert _same(whole[perm], permuted)


def test_finite_gaussians_match_the_float64_reference(cpu_ext):
    """Values and every gradient (pose included) of the well-defined Gaussians of the mixed set against the
    autograd projection in float64; the hard ones are left out of the reference (they make NaN there)."""
    vm, K = _cameras()
    inputs = _mixed_gaussians()
    keep = torch.ones(inputs[0].shape[0], dtype=torch.bool)
    keep[[5, 9, 12]] = False  # NaN / inf inputs
    inputs = [t[keep].contiguous() for t in inputs]
    n = int(keep.sum())
    grads = _upstream(2, n)
    fwd, bwd = _project(cpu_ext, inputs, vm, K, grads, 3, True)

    leaves = [t.double().requires_grad_() for t in inputs + [vm]]
    ref = project_gaussians(*leaves[:5], leaves[5], K.double(), W, H, sh_degree=3, antialiased=True)
    outs = [ref.means2d, ref.conics, ref.colors, ref.opacities, ref.depths]
    for got, want in zip(fwd[:5], outs, strict=True):
        torch.testing.assert_close(got.double(), want.detach(), rtol=2e-5, atol=1e-5)
    assert torch.equal(fwd[5], ref.radii)
    loss = sum((o * g.double()).sum() for o, g in zip(outs, grads, strict=True))
    want_grads = torch.autograd.grad(loss, leaves)
    for name, got, want in zip(
        ("means", "quats", "scales", "opac", "colors", "viewmats"), bwd, want_grads, strict=True
    ):
        scale = want.abs().max().clamp_min(1e-12)
        assert ((got.double() - want).abs().max() / scale) < 2e-5, name
