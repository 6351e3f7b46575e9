"""Rasterizer correctness: reference vs brute force and finite differences; CPU backend vs reference."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from go_core.camera import Camera
from go_core.render import render, render_camera, render_gaussians
from go_core.render.projection import project_gaussians
from go_core.render.synthetic import random_scene
from go_core.sh import eval_sh, sh_basis


@pytest.fixture(scope="session")
def cpu_ext():
    """Build (or load the cached) compiled rasterizer once per test session."""
    from go_core.render.build import load_extension

    return load_extension()


NAMES = ("means", "quats", "scales", "opacities", "sh", "viewmats", "means2d")


def _outputs(out) -> torch.Tensor:
    return torch.cat([out.rgb, out.alpha, out.depth], dim=-1)


def _rel(a: torch.Tensor, b: torch.Tensor) -> float:
    a, b = a.detach(), b.detach()
    return float((a - b).abs().max() / b.abs().max().clamp_min(1e-30)) if b.numel() else 0.0


def _brute_force(proj, cam: int, width: int, height: int) -> torch.Tensor:
    """Per-pixel loop over all Gaussians in depth order, with the tile rule (rgb only)."""
    img = torch.zeros(height, width, 3, dtype=torch.float64)
    order = torch.argsort(proj.depths[cam], stable=True).tolist()
    g = [
        (
            proj.means2d[cam, i].tolist(),
            proj.conics[cam, i].tolist(),
            float(proj.opacities[cam, i]),
            proj.colors[cam, i],
            int(proj.radii[cam, i]),
        )
        for i in order
    ]
    for j in range(height):
        for i in range(width):
            T, col = 1.0, torch.zeros(3, dtype=torch.float64)
            for (u, v), (a, b, c), o, rgb, r in g:
                tx, ty = i // 16, j // 16
                if r == 0 or not (math.floor((u - r) / 16) <= tx < math.ceil((u + r) / 16)):
                    continue
                if not (math.floor((v - r) / 16) <= ty < math.ceil((v + r) / 16)):
                    continue
                dx, dy = u - (i + 0.5), v - (j + 0.5)
                sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
                alpha = min(0.99, o * math.exp(-sigma))
                if sigma < 0 or alpha < 1 / 255:
                    continue
                if T * (1 - alpha) <= 1e-4:
                    break
                col += alpha * T * rgb
                T *= 1 - alpha
            img[j, i] = col
    return img


def test_sh_basis_orthonormal():
    # Monte-Carlo orthonormality of the real SH basis on the sphere (deg 3, 16 functions)
    g = torch.Generator().manual_seed(0)
    d = torch.nn.functional.normalize(torch.randn(400_000, 3, generator=g, dtype=torch.float64), dim=-1)
    Y = sh_basis(3, d)
    gram = 4 * math.pi * (Y.T @ Y) / d.shape[0]
    assert torch.allclose(gram, torch.eye(16, dtype=torch.float64), atol=0.02)
    # colour of a DC-only expansion is direction independent
    coeffs = torch.zeros(1, 16, 3, dtype=torch.float64)
    coeffs[0, 0] = 1.0
    colour = eval_sh(3, coeffs.expand(5, 16, 3), d[:5])
    assert torch.allclose(colour, torch.full((5, 3), 0.28209479177387814, dtype=torch.float64))


def test_reference_matches_brute_force():
    W, H = 37, 21  # odd sizes, 3x2 tiles with partial tiles
    scene = random_scene(25, W, H, cams=2, scale=0.12)
    out = render(*scene, W, H, sh_degree=3, backend="reference")
    proj = project_gaussians(*scene, W, H, sh_degree=3)
    for cam in range(2):
        ref = _brute_force(proj, cam, W, H)
        assert torch.allclose(out.rgb[cam], ref, atol=1e-12)
    assert (
        out.rgb.shape == (2, H, W, 3) and out.alpha.shape == (2, H, W, 1) and out.depth.shape == (2, H, W, 1)
    )


def _directional_fd_check(scene, W, H, grads, weights, antialiased=False, seed=0, h=1e-6, rtol=1e-5):
    """grad·v against a float64 central difference of the reference renderer, for every input."""
    gen = torch.Generator().manual_seed(seed)
    for k, name in enumerate(NAMES[:6]):
        for _ in range(2):
            direction = torch.randn(scene[k].shape, dtype=torch.float64, generator=gen)
            if name == "viewmats":
                direction[:, 3] = 0.0  # the last row of a viewmat is constant

            def f(step, k=k, direction=direction):
                args = list(scene)
                args[k] = scene[k] + step * direction
                out = render(*args, W, H, sh_degree=3, backend="reference", antialiased=antialiased)
                return float((_outputs(out) * weights).sum())

            # a step may cross one of the renderer's discontinuities (a 1/255 cut-off, a tile-rectangle
            # change); such a step gives a huge difference quotient, so a second, smaller step decides.
            an = float((grads[k].double() * direction).sum())
            scale = float((grads[k].double() * direction).abs().sum())  # float32 error is relative to this
            fds = []
            for step in (h, h / 7):
                fds.append((f(step) - f(-step)) / (2 * step))
                if abs(an - fds[-1]) <= rtol * scale + 1e-6:
                    break
            else:
                raise AssertionError(f"{name}: analytic {an} vs finite differences {fds}")


@pytest.mark.parametrize("antialiased", [False, True])
def test_reference_gradients_match_finite_differences(antialiased):
    W, H = 24, 18
    scene = random_scene(8, W, H, cams=2, scale=0.15, seed=1)
    weights = torch.randn(2, H, W, 5, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    _, grads = _grads(scene, W, H, "reference", torch.float64, weights, antialiased=antialiased)
    _directional_fd_check(scene, W, H, grads, weights, antialiased=antialiased)


def _grads(scene, W, H, backend, dtype, weights, sh_degree=3, antialiased=False, background=None):
    inputs = [t.detach().to(dtype).clone().requires_grad_() for t in scene[:6]]
    out = render(
        *inputs,
        scene[6].to(dtype),
        W,
        H,
        sh_degree=sh_degree,
        backend=backend,
        antialiased=antialiased,
        background=background,
    )
    out.means2d.retain_grad()
    (_outputs(out) * weights.to(dtype)).sum().backward()
    return out, [t.grad for t in inputs] + [out.means2d.grad]


@pytest.mark.parametrize("antialiased", [False, True])
def test_cpu_matches_float64_reference(cpu_ext, antialiased):
    W, H = 70, 45
    scene = random_scene(600, W, H, cams=2, seed=3)
    weights = torch.randn(2, H, W, 5, dtype=torch.float64, generator=torch.Generator().manual_seed(4))
    ref, gref = _grads(scene, W, H, "reference", torch.float64, weights, antialiased=antialiased)
    cpu, gcpu = _grads(scene, W, H, "cpu", torch.float32, weights, antialiased=antialiased)
    for k in ("rgb", "alpha", "depth"):
        assert _rel(getattr(cpu, k).double(), getattr(ref, k)) <= 1e-5, k
    assert torch.equal(cpu.radii, ref.radii)
    for name, a, b in zip(NAMES, gcpu, gref, strict=True):
        assert _rel(a.double(), b) <= 2e-5, name


def test_cpu_directional_derivative_matches_finite_differences(cpu_ext):
    """CPU gradients (all inputs incl. the pose) against a float64 central difference of the reference."""
    W, H = 40, 33
    scene = random_scene(60, W, H, cams=1, seed=5, scale=0.1)
    weights = torch.randn(1, H, W, 5, dtype=torch.float64, generator=torch.Generator().manual_seed(6))
    _, grads = _grads(scene, W, H, "cpu", torch.float32, weights)
    _directional_fd_check(scene, W, H, grads, weights, seed=7, rtol=2e-4)


@pytest.mark.parametrize("deg", [0, 1, 2])
def test_cpu_lower_sh_degrees_and_rgb_colors(cpu_ext, deg):
    W, H = 33, 30
    scene = random_scene(80, W, H, cams=1, seed=8, sh_degree=3)
    weights = torch.randn(1, H, W, 5, dtype=torch.float64, generator=torch.Generator().manual_seed(9))
    ref, gref = _grads(scene, W, H, "reference", torch.float64, weights, sh_degree=deg)
    cpu, gcpu = _grads(scene, W, H, "cpu", torch.float32, weights, sh_degree=deg)
    assert _rel(cpu.rgb.double(), ref.rgb) <= 1e-5
    assert _rel(gcpu[4].double(), gref[4]) <= 2e-5
    assert float(gcpu[4][:, (deg + 1) ** 2 :].abs().max()) == 0.0  # unused coefficients get no gradient
    rgb_scene = list(scene)
    rgb_scene[4] = torch.rand(80, 3, dtype=torch.float64)
    ref2, g2 = _grads(rgb_scene, W, H, "reference", torch.float64, weights, sh_degree=None)
    cpu2, c2 = _grads(rgb_scene, W, H, "cpu", torch.float32, weights, sh_degree=None)
    assert _rel(cpu2.rgb.double(), ref2.rgb) <= 1e-5 and _rel(c2[4].double(), g2[4]) <= 2e-5


def test_background_and_expected_depth(cpu_ext):
    W, H = 32, 32
    scene = random_scene(50, W, H, cams=2, seed=10)
    bg = torch.tensor([[0.2, 0.4, 0.6], [1.0, 0.0, 0.5]])
    out = render(*[t.float() for t in scene], W, H, sh_degree=3, background=bg, backend="cpu")
    plain = render(*[t.float() for t in scene], W, H, sh_degree=3, backend="cpu")
    assert torch.allclose(out.rgb, plain.rgb + (1 - plain.alpha) * bg[:, None, None, :], atol=1e-6)
    # one opaque-ish Gaussian: expected depth is its camera-space depth wherever it is visible
    means = torch.tensor([[0.0, 0.0, 0.0]])
    vm = torch.eye(4)[None].clone()
    vm[0, 2, 3] = 2.5
    K = torch.tensor([[[40.0, 0, 16], [0, 40.0, 16], [0, 0, 1]]])
    one = render(
        means,
        torch.tensor([[1.0, 0, 0, 0]]),
        torch.full((1, 3), 0.2),
        torch.tensor([0.9]),
        torch.ones(1, 3),
        vm,
        K,
        W,
        H,
        backend="cpu",
    )
    seen = one.alpha[..., 0] > 0.01
    assert seen.sum() > 20
    assert torch.allclose(one.depth[..., 0][seen], torch.tensor(2.5), rtol=1e-5)


def test_determinism_across_runs_and_threads(cpu_ext):
    W, H = 96, 80
    scene = random_scene(3000, W, H, cams=2, seed=11)
    weights = torch.randn(2, H, W, 5, dtype=torch.float64, generator=torch.Generator().manual_seed(12))
    threads = torch.get_num_threads()
    try:
        runs = []
        for nt in (threads, threads, 1):
            torch.set_num_threads(nt)
            runs.append(_grads(scene, W, H, "cpu", torch.float32, weights))
    finally:
        torch.set_num_threads(threads)
    (o0, g0) = runs[0]
    for o, g in runs[1:]:
        assert torch.equal(_outputs(o), _outputs(o0))
        for a, b in zip(g, g0, strict=True):
            assert torch.equal(a, b)


def test_fixed_cameras_skip_the_pose_gradient_and_change_nothing_else(cpu_ext):
    W, H = 64, 48
    scene = random_scene(800, W, H, cams=2, seed=5)
    weights = torch.randn(2, H, W, 5, dtype=torch.float64, generator=torch.Generator().manual_seed(6))
    _, with_pose = _grads(scene, W, H, "cpu", torch.float32, weights)
    inputs = [t.detach().float().clone().requires_grad_(i < 5) for i, t in enumerate(scene[:6])]
    out = render(*inputs, scene[6].float(), W, H, sh_degree=3, backend="cpu")
    (_outputs(out) * weights.float()).sum().backward()
    assert inputs[5].grad is None
    assert float(with_pose[5].abs().sum()) > 0
    for a, b in zip(with_pose[:5], [t.grad for t in inputs[:5]], strict=True):
        assert torch.equal(a, b)


def test_build_time_counts_only_real_builds(monkeypatch, tmp_path):
    import time as _time

    from torch.utils import cpp_extension

    from go_core.render import build

    def fake_load(name, build_directory, **_):
        library = Path(build_directory) / f"{name}.so"
        if not library.exists():  # like ninja: nothing to do when the library is up to date
            _time.sleep(0.2)  # stands for compiling
            library.write_bytes(b"")
        return "module"

    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path))
    monkeypatch.setattr(cpp_extension, "load", fake_load)
    before = build.BUILD_TIME.seconds
    try:
        build.load_extension.cache_clear()
        assert build.load_extension() == "module"
        built = build.BUILD_TIME.seconds - before
        assert 0.2 <= built < 2.0
        build.load_extension.cache_clear()
        build.load_extension()  # the .so is there now: only a load, no build time
        assert build.BUILD_TIME.seconds - before == built
    finally:
        build.load_extension.cache_clear()  # the real extension again for later tests
        build.BUILD_TIME.seconds = before


def test_build_key_and_missing_compiler(monkeypatch, tmp_path):
    from go_core.render import build

    key = build.build_key()
    assert key == build.build_key() and len(key) == 16
    # the same sources in another checkout get their own build dir (ninja files hold absolute paths)
    other = tmp_path / "checkout" / "go_core" / "render"
    for name in build.SOURCES + build.HEADERS:
        (other / name).parent.mkdir(parents=True, exist_ok=True)
        (other / name).write_bytes((build.HERE / name).read_bytes())
    monkeypatch.setattr(build, "HERE", other)
    monkeypatch.setattr(build, "CSRC", other / "csrc")
    other_key = build.build_key()
    assert other_key != key
    # a header is part of the binary too, and so is a kernel outside render/
    header = other / build.HEADERS[0]
    header.write_text(header.read_text() + "\n// edited\n")
    assert build.build_key() != other_key
    edited = build.build_key()
    adam = other / next(s for s in build.SOURCES if s.endswith("adam.cpp"))
    adam.write_text(adam.read_text() + "\n// edited\n")
    assert build.build_key() != edited
    monkeypatch.undo()
    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path))
    assert build.build_root() == tmp_path
    monkeypatch.setenv("CXX", "no-such-compiler-xyz")
    with pytest.raises(build.ExtensionBuildError, match="no-such-compiler-xyz"):
        build.check_compiler()


def test_render_gaussians_and_bad_inputs(cpu_ext):
    from go_core.gaussians import Gaussians

    g = Gaussians.from_points(torch.rand(20, 3) - 0.5, torch.rand(20, 3), torch.full((20,), 0.05), 0.7, 2)
    scene = random_scene(1, 32, 24, dtype=torch.float32)
    out = render_gaussians(g, scene[5], scene[6], 32, 24)
    assert out.rgb.shape == (1, 24, 32, 3) and out.alpha.max() > 0.1
    cam = Camera("c", 32, 24, scene[6][0].double().numpy(), scene[5][0].double().numpy())
    one = render_camera(g, cam)
    assert torch.equal(one.rgb, out.rgb) and torch.equal(one.alpha, out.alpha)
    with pytest.raises(ValueError, match="quats"):
        render(
            torch.zeros(3, 3),
            torch.zeros(2, 4),
            torch.zeros(3, 3),
            torch.zeros(3),
            torch.zeros(3, 3),
            scene[5],
            scene[6],
            32,
            24,
        )
    with pytest.raises(ValueError, match="backend"):
        render(*scene[:4], torch.zeros(1, 3), scene[5], scene[6], 32, 24, backend="metal")
