"""Surface terms of the coarse stage (go_core/coarse/depth_normal.py): analytic normals of a plane, the
Gaussians' normals, gradients by finite differences, and the loss on rendered sheets of discs."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from go_core.camera import look_at
from go_core.coarse.depth_normal import (
    camera_normals,
    depth_normal_loss,
    depth_normals,
    flatten_loss,
    valid_pixels,
)
from go_core.coarse.loop import optimize
from go_core.coarse.regularizers import RegularizerConfig, regularization_loss
from go_core.gaussians import Gaussians
from go_core.render import render

pytestmark = pytest.mark.usefixtures("single_thread")


def _K(size: int, f: float) -> torch.Tensor:
    return torch.tensor([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]], dtype=torch.float64)


def test_depth_normals_of_a_tilted_plane_are_its_normal():
    # the plane Z = a X + b Y + c (camera frame): along the ray (x, y, 1) its depth is c / (1 - a x - b y)
    size, a, b, c = 24, 0.4, -0.3, 3.0
    K = _K(size, 30.0)
    v, u = torch.meshgrid(torch.arange(size) + 0.5, torch.arange(size) + 0.5, indexing="ij")
    x, y = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
    depth = (c / (1 - a * x - b * y)).to(torch.float64)
    n = depth_normals(depth, K)
    want = torch.tensor([a, b, -1.0], dtype=torch.float64) / math.sqrt(a * a + b * b + 1)
    assert torch.allclose(n[1:-1, 1:-1], want.expand(size - 2, size - 2, 3), atol=1e-12)
    assert torch.all(n[0] == 0) and torch.all(n[:, -1] == 0)  # the border has no central difference


def test_camera_normals_take_the_smallest_axis_and_face_the_camera():
    angle = 0.7  # a rotation about x: the local y axis becomes (0, cos, sin)
    quat = torch.tensor([[math.cos(angle / 2), math.sin(angle / 2), 0.0, 0.0]] * 2, dtype=torch.float64)
    log_scales = torch.log(torch.tensor([[1.0, 0.01, 0.5], [1.0, 0.01, 0.5]], dtype=torch.float64))
    means = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, -2.0]], dtype=torch.float64)  # in front / behind
    viewmat = torch.eye(4, dtype=torch.float64)  # camera frame = world frame
    n = camera_normals(quat, log_scales, means, viewmat)
    axis = torch.tensor([0.0, math.cos(angle), math.sin(angle)], dtype=torch.float64)
    assert torch.allclose(n[0], -axis) and torch.allclose(n[1], axis)  # n · mean < 0 for both
    assert torch.allclose(n.norm(dim=1), torch.ones(2, dtype=torch.float64))


def test_flatten_loss_value_and_gradient():
    log_scales = torch.log(torch.tensor([[0.2, 0.1, 0.4], [0.3, 0.5, 0.05]], dtype=torch.float64))
    log_scales.requires_grad_(True)
    loss = flatten_loss(log_scales, extent=2.0)
    assert loss.item() == pytest.approx((0.1 + 0.05) / 2 / 2.0)
    assert torch.autograd.gradcheck(lambda t: flatten_loss(t, 2.0), (log_scales,))
    g = RegularizerConfig(lambda_opacity=0.0, lambda_anisotropy=0.0, lambda_flatten=3.0)
    gs = Gaussians.from_points(torch.zeros(2, 3), torch.rand(2, 3), torch.full((2,), 0.1), 0.5, 0)
    total, parts = regularization_loss(g, gs, torch.rand(4, 4), None, extent=2.0)
    assert set(parts) == {"flatten"}
    assert float(total) == pytest.approx(3.0 * 0.1 / 2.0, rel=1e-6)


def test_depth_normal_loss_gradient_matches_finite_differences():
    gen = torch.Generator().manual_seed(0)
    size = 8
    depth = (2.0 + 0.1 * torch.rand(size, size, generator=gen, dtype=torch.float64)).requires_grad_(True)
    normals = torch.randn(size, size, 3, generator=gen, dtype=torch.float64).requires_grad_(True)
    valid = valid_pixels(torch.ones(size, size), torch.ones(size, size))
    assert int(valid.sum()) == (size - 2) ** 2
    K = _K(size, 10.0)
    assert torch.autograd.gradcheck(lambda n, d: depth_normal_loss(n, d, K, valid), (normals, depth))


def _sheet(tilt: float) -> tuple[Gaussians, object]:
    """A 15 x 15 grid of flat discs on the plane z = 0 seen head-on from z = 3, each disc turned by ``tilt``
    (rad) about x: at 0 their normals are the sheet's."""
    size = 32
    K = np.array([[40.0, 0, size / 2], [0, 40.0, size / 2], [0, 0, 1]])
    cam = look_at("c", np.array([0, 0, 3.0]), np.zeros(3), np.array([0, 1.0, 0]), K, size, size)
    xs = torch.linspace(-1.6, 1.6, 15)
    gx, gy = torch.meshgrid(xs, xs, indexing="ij")
    means = torch.stack([gx.flatten(), gy.flatten(), torch.zeros(225)], 1)
    g = Gaussians.from_points(means, torch.full((225, 3), 0.5), torch.full((225,), 0.15), 0.9, 0)
    g.log_scales[:, 2] = math.log(1e-3)
    g.quats[:] = torch.tensor([math.cos(tilt / 2), math.sin(tilt / 2), 0.0, 0.0])
    return g, cam


def _sheet_loss(tilt: float) -> tuple[float, float]:
    g, cam = _sheet(tilt)
    vm, K = cam.viewmat_tensor()[None], cam.K_tensor()
    out = render(g.means, g.quats, g.scales(), g.opacities(), g.sh[:, 0], vm, K[None], 32, 32)
    normals = camera_normals(g.quats, g.log_scales, g.means, vm[0])
    n_out = render(g.means, g.quats, g.scales(), g.opacities(), normals, vm, K[None], 32, 32)
    valid = valid_pixels(out.alpha[0, ..., 0], torch.ones(32, 32))
    assert int(valid.sum()) > 500
    loss = float(depth_normal_loss(n_out.rgb[0], out.depth[0, ..., 0], K, valid))
    return loss, float(out.alpha[0, ..., 0][valid].mean())


def test_a_sheet_of_discs_agrees_with_its_depth_and_tilted_discs_do_not():
    # the rendered normal is alpha-weighted (not normalised, as in 2DGS): the loss is 1 - alpha cos(tilt),
    # the splats' depth being their centres' (the sheet's plane at any tilt)
    flat, alpha = _sheet_loss(0.0)
    assert alpha > 0.95 and flat == pytest.approx(1.0 - alpha, abs=2e-3)
    tilted, alpha = _sheet_loss(1.0)
    assert alpha > 0.8 and tilted == pytest.approx(1.0 - alpha * math.cos(1.0), abs=5e-3)


def test_loop_with_the_surface_terms_is_deterministic_and_logs_them():
    from tests.test_training import _init, _tiny_config, _views

    init, views = _init(), _views()
    cfg = replace(_tiny_config(20), lambda_flatten=1.0, lambda_depth_normal=0.1, depth_normal_from=5)
    a, sa = optimize(init, views, cfg, generator=torch.Generator().manual_seed(5))
    b, _ = optimize(init, views, cfg, generator=torch.Generator().manual_seed(5))
    for name, t in a.tensors().items():
        assert torch.equal(getattr(b, name), t), name
    assert {"flatten", "depth_normal"} <= set(sa.loss_log[-1])
    c, _ = optimize(init, views, _tiny_config(20), generator=torch.Generator().manual_seed(5))
    assert not torch.equal(c.means, a.means)
