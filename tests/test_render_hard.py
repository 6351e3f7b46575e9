"""Numerically hard inputs: outputs and gradients stay finite, results stay meaningful (CPU + reference)."""

from __future__ import annotations

import pytest
import torch

from go_core.render import render
from go_core.render.synthetic import random_scene


@pytest.fixture(scope="module")
def cpu_ext():
    from go_core.render.build import load_extension

    return load_extension()


def _camera(width=48, height=40, z=3.0, dtype=torch.float32):
    vm = torch.eye(4, dtype=dtype)[None].clone()
    vm[0, 2, 3] = z
    f = 1.1 * max(width, height)
    K = torch.tensor([[[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]]], dtype=dtype)
    return vm, K


def _run(means, quats, scales, opac, colors, vm, K, W, H, backend, sh_degree=None, **kw):
    """Forward + backward of a generic loss; asserts every output and gradient is finite."""
    inputs = [t.clone().requires_grad_() for t in (means, quats, scales, opac, colors, vm)]
    out = render(*inputs, K, W, H, sh_degree=sh_degree, backend=backend, **kw)
    out.means2d.retain_grad()
    loss = out.rgb.sum() + out.alpha.square().sum() + 0.01 * out.depth.sum()
    loss.backward()
    for name in ("rgb", "alpha", "depth", "means2d"):
        assert torch.isfinite(getattr(out, name)).all(), name
    for name, t in zip(("means", "quats", "scales", "opacities", "colors", "viewmats"), inputs, strict=True):
        assert t.grad is not None and torch.isfinite(t.grad).all(), name
    if out.means2d.grad is not None:
        assert torch.isfinite(out.means2d.grad).all()
    assert (out.alpha >= 0).all() and (out.alpha <= 1).all()
    return out, [t.grad for t in inputs]


BACKENDS = ["cpu", "reference"]


@pytest.mark.parametrize("backend", BACKENDS)
def test_tiny_and_huge_scales(cpu_ext, backend):
    g = torch.Generator().manual_seed(0)
    n = 40
    means = torch.rand(n, 3, generator=g) - 0.5
    scales = torch.where(torch.arange(n)[:, None] % 2 == 0, torch.full((n, 3), 1e-7), torch.full((n, 3), 1e3))
    scales[::5] = torch.tensor([1e3, 1e-7, 1e-7])  # mixed: a needle
    W, H = (48, 40) if backend == "cpu" else (20, 16)
    vm, K = _camera(W, H)
    out, _ = _run(
        means,
        torch.randn(n, 4, generator=g),
        scales,
        torch.full((n,), 0.5),
        torch.rand(n, 3, generator=g),
        vm,
        K,
        W,
        H,
        backend,
        antialiased=True,
    )
    assert out.alpha.max() > 0.5  # the huge Gaussians cover the image


def test_tiny_scale_matches_reference_and_is_a_dilated_point(cpu_ext):
    means = torch.zeros(1, 3)
    vm, K = _camera()
    args = (
        means,
        torch.tensor([[1.0, 0, 0, 0]]),
        torch.full((1, 3), 1e-7),
        torch.tensor([0.8]),
        torch.ones(1, 3),
    )
    cpu, _ = _run(*args, vm, K, 48, 40, "cpu")
    ref, _ = _run(*[a.double() for a in args], vm.double(), K.double(), 48, 40, "reference")
    assert torch.allclose(cpu.rgb.double(), ref.rgb, atol=1e-6)
    # a point blurred by the 0.3 px² filter: peak alpha = 0.8 * exp(-0.5 * d²/0.3) at the nearest pixel centre
    assert (
        abs(float(cpu.alpha.detach().max()) - 0.8 * float(torch.exp(torch.tensor(-0.5 * 0.5 / 0.3)))) < 1e-5
    )


@pytest.mark.parametrize("backend", BACKENDS)
def test_zero_and_unnormalised_quaternions(cpu_ext, backend):
    W, H = (48, 40) if backend == "cpu" else (20, 16)
    scene = [t.float() for t in random_scene(30, W, H, sh_degree=1, seed=3)]
    means, quats, scales, opac, sh, vm, K = scene
    ident = torch.zeros_like(quats)
    ident[:, 0] = 1.0
    a, _ = _run(means, ident, scales, opac, sh, vm, K, W, H, backend, sh_degree=1)
    b, grads = _run(means, torch.zeros_like(quats), scales, opac, sh, vm, K, W, H, backend, sh_degree=1)
    assert torch.allclose(a.rgb, b.rgb, atol=1e-6)  # a zero quaternion means no rotation
    c, _ = _run(means, quats * 37.0, scales, opac, sh, vm, K, W, H, backend, sh_degree=1)
    d, _ = _run(means, quats, scales, opac, sh, vm, K, W, H, backend, sh_degree=1)
    assert torch.allclose(c.rgb, d.rgb, atol=1e-5)


def test_extreme_anisotropy_matches_reference(cpu_ext):
    g = torch.Generator().manual_seed(4)
    n = 30
    means = torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5
    scales = torch.tensor([[0.5, 1e-5, 1e-5]], dtype=torch.float64).repeat(n, 1)
    quats = torch.randn(n, 4, generator=g, dtype=torch.float64)
    args = (
        means,
        quats,
        scales,
        torch.full((n,), 0.7, dtype=torch.float64),
        torch.rand(n, 3, generator=g, dtype=torch.float64),
    )
    vm, K = _camera(dtype=torch.float64)
    ref, gref = _run(*args, vm, K, 48, 40, "reference")
    cpu, gcpu = _run(*[a.float() for a in args], vm.float(), K.float(), 48, 40, "cpu")
    assert (ref.alpha > 0.1).sum() > 50
    assert float((cpu.rgb.detach().double() - ref.rgb.detach()).abs().max()) < 1e-4
    assert torch.equal(cpu.radii, ref.radii)


@pytest.mark.parametrize("backend", BACKENDS)
def test_near_plane(cpu_ext, backend):
    near = 0.25  # exactly representable, so "on the plane" is exact in float32
    z = torch.tensor([near, near + 1e-6, near - 1e-6, 1e-9, 0.0, -1e-6, -1.0, 0.5, 2.0])
    n = len(z)
    means = torch.stack([torch.full((n,), 1e-3), torch.zeros(n), z], -1)
    vm, K = _camera(z=0.0)
    out, grads = _run(
        means,
        torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        torch.full((n, 3), 0.05),
        torch.full((n,), 0.6),
        torch.rand(n, 3, generator=torch.Generator().manual_seed(5)),
        vm,
        K,
        48,
        40,
        backend,
        near_plane=near,
    )
    radii = out.radii[0]
    assert (radii[z < near] == 0).all() and (radii[z >= near] > 0).all()
    assert (grads[0][z < near] == 0).all()  # culled Gaussians get no gradient


@pytest.mark.parametrize("backend", BACKENDS)
def test_camera_inside_the_cloud(cpu_ext, backend):
    g = torch.Generator().manual_seed(6)
    n = 400
    means = torch.randn(n, 3, generator=g)  # around the camera, in every direction, some within 1e-3
    means[:5] *= 1e-3
    vm, K = _camera(z=0.0)
    out, _ = _run(
        means,
        torch.randn(n, 4, generator=g),
        torch.rand(n, 3, generator=g) * 0.3,
        torch.rand(n, generator=g),
        torch.randn(n, 4, 3, generator=g),
        vm,
        K,
        48,
        40,
        backend,
        sh_degree=1,
    )
    visible = out.radii[0] > 0
    assert not (visible & (means[:, 2] < 0.01)).any() and visible.sum() > 50
    assert out.alpha.max() > 0.9


def test_one_hundred_thousand_on_one_pixel(cpu_ext):
    n = 100_000
    means = torch.zeros(n, 3)
    vm, K = _camera(48, 40)
    colors = torch.rand(n, 3, generator=torch.Generator().manual_seed(7))
    args = (
        means,
        torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        torch.full((n, 3), 1e-3),
        torch.full((n,), 0.5),
        colors,
        vm,
        K,
        48,
        40,
        "cpu",
    )
    out, grads = _run(*args)
    centre = out.alpha[0, 20, 24, 0]
    # front to back, each α = 0.5·exp(-σ): the pixel saturates and stops before T ≤ 1e-4
    assert 0.999 < float(centre.detach()) <= 1 - 1e-4 + 1e-6
    # only Gaussians composited before the pixels stop matter (faint edge pixels need ~2k of them)
    assert 10 < int((grads[3] != 0).sum()) < 5000
    # equal depths: ties keep index order, so the front-most is Gaussian 0 and the result is deterministic
    again, _ = _run(*args)
    assert torch.equal(out.rgb, again.rgb)


@pytest.mark.parametrize("backend", BACKENDS)
def test_empty_scene_and_all_culled(cpu_ext, backend):
    vm, K = _camera(31, 17)
    bg = torch.tensor([0.1, 0.2, 0.3])
    empty = render(
        torch.zeros(0, 3),
        torch.zeros(0, 4),
        torch.zeros(0, 3),
        torch.zeros(0),
        torch.zeros(0, 3),
        vm,
        K,
        31,
        17,
        background=bg,
        backend=backend,
    )
    assert empty.rgb.shape == (1, 17, 31, 3) and torch.allclose(empty.rgb, bg.expand(1, 17, 31, 3))
    assert (empty.alpha == 0).all() and torch.isfinite(empty.depth).all() and empty.radii.shape == (1, 0)
    n = 20
    behind = torch.randn(n, 3, generator=torch.Generator().manual_seed(8))
    behind[:, 2] = -5.0  # camera at z=-3 looks along +z: these are behind it
    out, grads = _run(
        behind,
        torch.randn(n, 4),
        torch.full((n, 3), 0.1),
        torch.full((n,), 0.9),
        torch.rand(n, 3),
        vm,
        K,
        31,
        17,
        backend,
    )
    assert (out.radii == 0).all() and (out.alpha == 0).all()
    assert all(float(g.abs().max()) == 0.0 for g in grads)


@pytest.mark.parametrize("size", [(1, 1), (17, 5), (5, 33), (16, 16), (33, 17)])
def test_odd_image_sizes_match_reference(cpu_ext, size):
    W, H = size
    scene = random_scene(40, W, H, cams=2, seed=9, scale=0.2)
    ref = render(*scene, W, H, sh_degree=3, backend="reference")
    cpu = render(*[t.float() for t in scene], W, H, sh_degree=3, backend="cpu")
    assert cpu.rgb.shape == (2, H, W, 3)
    assert float((cpu.rgb.double() - ref.rgb).abs().max()) < 1e-5


@pytest.mark.parametrize(
    "field,index,value,what",
    [
        ("means", (3, 0), float("nan"), "means not finite"),
        ("means", (5, 2), float("inf"), "means not finite"),
        ("quats", (7, 1), float("nan"), "quaternions not finite"),
        ("log_scales", (2, 0), float("inf"), "scales not finite or >= 1e20"),
        ("log_scales", (4, 1), 46.1, "scales not finite or >= 1e20"),  # exp(46.1) > 1e20: would vanish
        ("opacity_logits", (6,), float("nan"), "opacities not finite"),
        ("sh", (1, 0, 2), float("-inf"), r"colours \(SH\) not finite"),
    ],
)
def test_invalid_gaussians_give_one_clear_error_at_step_start(tmp_path, field, index, value, what):
    """NaN/inf means, quaternions, opacities or colours and scales >= 1e20 (which the rasterizer turns into
    NaN gradients or drops silently) are one error naming the file, the count and the first index, when a
    step loads the model or starts optimising it."""
    from go_core.coarse.loop import CoarseConfig, optimize
    from go_core.errors import InvalidGaussiansError
    from go_core.gaussians import Gaussians

    g = Gaussians.from_points(torch.rand(10, 3), torch.rand(10, 3), torch.full((10,), 0.05), 0.5, 1)
    getattr(g, field)[index] = value
    path = g.save(tmp_path / "gaussians.npz")
    expected = f"gaussians.npz: 1 of 10 Gaussians have {what}.* .first: index {index[0]}\\)"
    with pytest.raises(InvalidGaussiansError, match=expected):
        Gaussians.load(path)
    with pytest.raises(InvalidGaussiansError, match=what):
        optimize(g, [object()], CoarseConfig(iterations=1), generator=torch.Generator(), extent=1.0)
    ok = Gaussians.from_points(torch.rand(10, 3), torch.rand(10, 3), torch.full((10,), 1e3), 0.5, 1)
    Gaussians.load(ok.save(tmp_path / "ok.npz"))  # large but finite scales are fine
