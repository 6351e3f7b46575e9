"""Expected depth on its own (the mesh step fuses it): the CPU backend against the float64 reference, the
reference's depth gradients against finite differences, and the depth of a known surface."""

from __future__ import annotations

import numpy as np
import torch

from go_core.render import render
from go_core.render.synthetic import random_scene
from tests.test_render import _directional_fd_check, _grads, _rel, cpu_ext  # noqa: F401  (fixture)


def _depth_only(cams: int, H: int, W: int, seed: int) -> torch.Tensor:
    """Loss weights on the depth channel only (rgb, alpha get 0): gradients are those of the depth alone."""
    w = torch.zeros(cams, H, W, 5, dtype=torch.float64)
    w[..., 4] = torch.randn(cams, H, W, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    return w


def test_depth_gradients_match_finite_differences():
    W, H = 24, 18
    scene = random_scene(8, W, H, cams=2, scale=0.15, seed=11)
    weights = _depth_only(2, H, W, 12)
    _, grads = _grads(scene, W, H, "reference", torch.float64, weights)
    _directional_fd_check(scene, W, H, grads, weights, seed=13)


def test_cpu_depth_and_its_gradients_match_float64_reference(cpu_ext):  # noqa: F811
    W, H = 70, 45
    scene = random_scene(600, W, H, cams=2, seed=14)
    weights = _depth_only(2, H, W, 15)
    ref, gref = _grads(scene, W, H, "reference", torch.float64, weights)
    cpu, gcpu = _grads(scene, W, H, "cpu", torch.float32, weights)
    seen = ref.alpha[..., 0] > 1e-3  # the depth of a nearly empty pixel divides by ~0: compare where seen
    assert _rel(cpu.depth[..., 0][seen].double(), ref.depth[..., 0][seen]) <= 1e-5
    for a, b in zip(gcpu[:6], gref[:6], strict=True):
        assert _rel(a.double(), b) <= 2e-5


def test_depth_of_a_wall_of_flat_gaussians_is_its_distance(cpu_ext):  # noqa: F811
    """A fronto-parallel wall of overlapping flat Gaussians at z = 2.5: expected depth 2.5 where covered."""
    xs = torch.linspace(-1.0, 1.0, 21, dtype=torch.float64)
    gx, gy = torch.meshgrid(xs, xs, indexing="ij")
    n = gx.numel()
    means = torch.stack([gx.reshape(-1), gy.reshape(-1), torch.full((n,), 2.5, dtype=torch.float64)], 1)
    quats = torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64).expand(n, 4)
    scales = torch.tensor([[0.08, 0.08, 1e-4]], dtype=torch.float64).expand(n, 3)
    opac = torch.full((n,), 0.9, dtype=torch.float64)
    colours = torch.rand(n, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    K = torch.tensor([[[40.0, 0, 16], [0, 40.0, 16], [0, 0, 1]]], dtype=torch.float64)
    view = torch.eye(4, dtype=torch.float64)[None]
    for backend, dtype in (("reference", torch.float64), ("cpu", torch.float32)):
        args = [t.to(dtype) for t in (means, quats, scales, opac, colours, view, K)]
        out = render(*args, 32, 32, backend=backend)
        covered = out.alpha[0, ..., 0] > 0.5
        assert covered.float().mean() > 0.9
        assert np.allclose(out.depth[0, ..., 0][covered].numpy(), 2.5, rtol=1e-5), backend


def _projected(backend: str, W: int, H: int, scene, dtype):
    from go_core.render.cpu import project_cpu
    from go_core.render.projection import project_gaussians

    means, quats, scales, opac, _, vms, Ks = (t.to(dtype) for t in scene)
    cols = torch.zeros(len(means), 3, dtype=dtype)
    project = project_gaussians if backend == "reference" else project_cpu
    return project(means, quats, scales, opac, cols, vms, Ks, W, H)


def test_cpu_median_depth_matches_float64_reference(cpu_ext):  # noqa: F811
    """Same stopping Gaussian per pixel: NaN (opacity never reaches 1/2) on the same pixels and the same
    depth elsewhere, but for pixels whose transmittance lands within float32 rounding of 1/2."""
    from go_core.render.cpu import median_depth_cpu
    from go_core.render.reference import median_depth_reference

    W, H = 70, 45
    scene = random_scene(600, W, H, cams=2, seed=14)
    p = _projected("reference", W, H, scene, torch.float64)
    ref = median_depth_reference(p, W, H)
    q = _projected("cpu", W, H, scene, torch.float32)
    cpu = median_depth_cpu(q, W, H).double()
    assert 0.05 < torch.isnan(ref).float().mean() < 0.95  # both kinds of pixel are tested
    same = (torch.isnan(ref) & torch.isnan(cpu)) | ((cpu - ref).abs() <= 1e-5 * ref.abs())
    assert same.float().mean() >= 0.999


def _two_walls(front_opacity: float) -> list[torch.Tensor]:
    """One wide Gaussian at z = 2 (opacity ``front_opacity``) in front of one at z = 3 (opacity 0.9),
    both flat and facing a camera at the origin: near the image centre alpha ≈ each opacity."""
    means = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 3.0]], dtype=torch.float64)
    quats = torch.tensor([[1.0, 0, 0, 0]] * 2, dtype=torch.float64)
    scales = torch.tensor([[5.0, 5.0, 1e-4]] * 2, dtype=torch.float64)
    opac = torch.tensor([front_opacity, 0.9], dtype=torch.float64)
    K = torch.tensor([[[40.0, 0, 16], [0, 40.0, 16], [0, 0, 1]]], dtype=torch.float64)
    view = torch.eye(4, dtype=torch.float64)[None]
    return [means, quats, scales, opac, torch.zeros(2, 3, dtype=torch.float64), view, K]


def test_median_depth_of_a_translucent_wall_is_the_surface_behind_it(cpu_ext):  # noqa: F811
    """Front wall at opacity 0.3: the expected depth lies between the walls (2.68 at the centre), the median
    depth is the back wall's 3; at opacity 0.7 the median is the front wall's 2. Both backends."""
    from go_core.gaussians import Gaussians
    from go_core.render.api import render_median_depth

    for front, median in ((0.3, 3.0), (0.7, 2.0)):
        args = _two_walls(front)
        exp_depth = render(*args, 32, 32, backend="reference").depth[0, 16, 16, 0].item()
        if front < 0.5:
            assert 2.5 < exp_depth < 2.9
        g = Gaussians(args[0], args[1], args[2].log(), torch.logit(args[3]), args[4][:, None, :])
        for backend in ("reference", "cpu"):
            med = render_median_depth(g, args[5], args[6], 32, 32, backend=backend)[0]
            centre = med[12:20, 12:20].double()
            assert torch.allclose(centre, torch.tensor(median, dtype=torch.float64)), backend
