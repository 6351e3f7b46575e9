"""Deterministic synthetic Gaussian scenes for the rasterizer tests and benchmark."""

from __future__ import annotations

import torch

from go_core.seeding import torch_generator


def look_at_viewmat(eye, target, dtype=torch.float64) -> torch.Tensor:
    """World-to-camera (OpenCV) matrix of a camera at ``eye`` looking at ``target`` with world -y up."""
    eye = torch.as_tensor(eye, dtype=dtype)
    fwd = torch.as_tensor(target, dtype=dtype) - eye
    fwd = fwd / fwd.norm()
    up = torch.tensor([0.0, -1.0, 0.0], dtype=dtype)
    right = torch.linalg.cross(up, fwd)
    right = right / right.norm()
    down = torch.linalg.cross(fwd, right)
    R = torch.stack([right, down, fwd])
    vm = torch.eye(4, dtype=dtype)
    vm[:3, :3] = R
    vm[:3, 3] = -R @ eye
    return vm


def random_scene(
    n: int,
    width: int,
    height: int,
    *,
    cams: int = 1,
    sh_degree: int = 3,
    seed: int = 0,
    dtype=torch.float64,
    scale: float = 0.06,
    spread: float = 0.6,
):
    """Gaussians in a ball seen by ``cams`` cameras on a circle of radius 3 (inputs ready for render())."""
    g = torch_generator(seed)
    means = (torch.rand(n, 3, generator=g, dtype=dtype) - 0.5) * 2 * spread
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    scales = torch.exp(torch.randn(n, 3, generator=g, dtype=dtype) * 0.4) * scale
    opac = torch.rand(n, generator=g, dtype=dtype) * 0.85 + 0.1
    sh = torch.randn(n, (sh_degree + 1) ** 2, 3, generator=g, dtype=dtype) * 0.3
    sh[:, 0] += 0.5
    vms, Ks = [], []
    for c in range(cams):
        ang = 0.6 * c
        eye = [3.0 * float(torch.sin(torch.tensor(ang))), 0.3, -3.0 * float(torch.cos(torch.tensor(ang)))]
        vms.append(look_at_viewmat(eye, [0.0, 0.0, 0.0], dtype))
        f = 1.1 * max(width, height)
        Ks.append(torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=dtype))
    return means, quats, scales, opac, sh, torch.stack(vms), torch.stack(Ks)


def benchmark_scene(
    n: int,
    size: int,
    *,
    seed: int = 0,
    sigma_px: tuple[float, float] = (1.0, 8.0),
    sh_degree: int = 3,
    dtype=torch.float32,
):
    """A realistic load: n Gaussians in a unit ball seen from 3 units away by one size x size camera.

    Screen-space standard deviations are log-uniform in ``sigma_px`` (pixels), anisotropy up to ~3:1,
    opacities in [0.05, 1), so tiles hold a few hundred to a few thousand Gaussians, as in training.
    """
    g = torch_generator(seed)
    f = 1.2 * size
    dist = 3.0
    d = torch.randn(n, 3, generator=g, dtype=torch.float64)
    means = d / d.norm(dim=-1, keepdim=True) * torch.rand(n, 1, generator=g, dtype=torch.float64) ** (1 / 3)
    lo, hi = torch.log(torch.tensor(sigma_px, dtype=torch.float64))
    sig = torch.exp(lo + (hi - lo) * torch.rand(n, 1, generator=g, dtype=torch.float64)) * dist / f
    scales = sig * torch.exp(torch.rand(n, 3, generator=g, dtype=torch.float64) * 1.1 - 0.55)
    quats = torch.randn(n, 4, generator=g, dtype=torch.float64)
    opac = torch.rand(n, generator=g, dtype=torch.float64) * 0.95 + 0.05
    sh = torch.randn(n, (sh_degree + 1) ** 2, 3, generator=g, dtype=torch.float64) * 0.2
    vm = look_at_viewmat([0.0, 0.0, -dist], [0.0, 0.0, 0.0])[None]
    K = torch.tensor([[[f, 0, size / 2], [0, f, size / 2], [0, 0, 1]]], dtype=torch.float64)
    return tuple(t.to(dtype) for t in (means, quats, scales, opac, sh, vm, K))
