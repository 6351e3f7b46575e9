"""Tile binning of the compiled rasterizer: it drops the tiles of a Gaussian's 3-sigma rectangle that no pixel
of it can reach (alpha >= 1/255), and nothing else; compositing results stay those of the reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from go_core.render.cpu import rasterize_cpu
from go_core.render.reference import rasterize_reference
from go_core.render.tiles import TILE, tile_grid, tile_rects

W, H = 100, 90


@pytest.fixture(scope="module")
def cpu_ext():
    from go_core.render.build import load_extension

    return load_extension()


def _conics(theta: torch.Tensor, s1: torch.Tensor, s2: torch.Tensor) -> torch.Tensor:
    """Upper triangles (a, b, c) of the inverse covariances of 2D Gaussians with axes s1, s2 rotated by
    theta."""
    cs, sn = torch.cos(theta), torch.sin(theta)
    rot = torch.stack([torch.stack([cs, -sn], -1), torch.stack([sn, cs], -1)], -2)
    cov = rot @ torch.diag_embed(torch.stack([s1**2, s2**2], -1)) @ rot.transpose(-1, -2)
    inv = torch.linalg.inv(cov)
    return torch.stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]], -1)


def _hard_2d_gaussians(n: int, seed: int) -> dict[str, torch.Tensor]:
    """Rotated, very anisotropic (up to 300:1), tiny to large, low to full opacity (some below 1/255),
    centres partly off-screen: the cases where a 3-sigma rectangle is a poor fit."""
    gen = torch.Generator().manual_seed(seed)

    def u(*shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=gen, dtype=torch.float64)

    means = u(n, 2) * torch.tensor([W + 60.0, H + 60.0], dtype=torch.float64) - 30.0
    theta = u(n) * math.pi
    s1 = 10 ** (u(n) * 2.0 - 0.5)  # 0.3 .. 30 px
    s2 = s1 * 10 ** (-u(n) * 2.5)
    return {
        "means2d": means.float()[None],
        "conics": _conics(theta, s1, s2).float()[None],
        "feats": u(n, 4).float()[None],
        "opacities": (10 ** (-u(n) * 3.0)).float()[None],
        "depths": (1.0 + u(n)).float()[None],
        "radii": torch.ceil(3.0 * s1).to(torch.int32)[None],
    }


def _reachable_pairs(d: dict[str, torch.Tensor]) -> set[tuple[int, int]]:
    """(tile, gaussian) pairs with a pixel of the tile inside the Gaussian's 3-sigma rectangle at which
    alpha >= 1/255 (float64, with a 1e-3 slack in the exponent: stricter than the kernel needs)."""
    m = d["means2d"][0].double().numpy()
    a, b, c = d["conics"][0].double().numpy().T
    o = d["opacities"][0].double().numpy()
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    dx = m[:, 0, None, None] - xs
    dy = m[:, 1, None, None] - ys
    sigma = 0.5 * (a[:, None, None] * dx**2 + c[:, None, None] * dy**2) + b[:, None, None] * dx * dy
    reach = (sigma >= 0) & (sigma <= np.log(np.maximum(o * 255.0, 1e-300))[:, None, None] + 1e-3)
    rect = tile_rects(d["means2d"][0], d["radii"][0], W, H).numpy()
    tx, _ = tile_grid(W, H)
    pairs = set()
    for i, y, x in zip(*np.nonzero(reach), strict=True):
        t_x, t_y = x // TILE, y // TILE
        x0, x1, y0, y1 = rect[i]
        if x0 <= t_x < x1 and y0 <= t_y < y1:
            pairs.add((int(t_y * tx + t_x), int(i)))
    return pairs


def _bin(ext, d: dict[str, torch.Tensor]) -> list[torch.Tensor]:
    return ext.bin_and_pack(
        d["means2d"],
        d["conics"],
        d["feats"][..., :3].contiguous(),
        d["feats"][..., 3].contiguous(),
        d["opacities"],
        d["depths"],
        d["radii"],
        W,
        H,
    )


@pytest.mark.parametrize("seed", [0, 1])
def test_binning_keeps_every_reachable_tile_and_drops_the_rest(cpu_ext, seed):
    d = _hard_2d_gaussians(600, seed)
    _, toff, gid, goff, gpos = _bin(cpu_ext, d)
    toff, gid, goff, gpos = toff.numpy(), gid.numpy(), goff.numpy(), gpos.numpy()
    tx, ty = tile_grid(W, H)
    kept = {(t, int(n)) for t in range(tx * ty) for n in gid[toff[t] : toff[t + 1]]}
    assert len(kept) == len(gid)  # no pair twice

    reachable = _reachable_pairs(d)
    assert len(reachable) > 400
    assert reachable <= kept, f"dropped reachable pairs: {sorted(reachable - kept)[:5]}"

    rect = tile_rects(d["means2d"][0], d["radii"][0], W, H).numpy()
    rect_pairs = {
        (y * tx + x, i)
        for i, (x0, x1, y0, y1) in enumerate(rect)
        for y in range(y0, y1)
        for x in range(x0, x1)
        if d["opacities"][0, i] >= 1 / 255
    }
    assert kept <= rect_pairs
    # the culling must pay: most unreachable rectangle tiles are gone
    assert len(kept - reachable) < 0.25 * len(rect_pairs - reachable)

    depth = d["depths"][0].numpy()
    for t in range(tx * ty):
        z = depth[gid[toff[t] : toff[t + 1]]]
        assert np.all(np.diff(z) >= 0), f"tile {t} not front to back"
    # each Gaussian's list of intersections: its own entries, in row-major tile order (the backward sums them
    # in this order, which makes gradients deterministic)
    tile_of = np.searchsorted(toff, np.arange(len(gid)), side="right") - 1
    for n in range(len(depth)):
        pos = gpos[goff[n] : goff[n + 1]]
        assert np.all(gid[pos] == n)
        assert np.all(np.diff(tile_of[pos]) > 0)
        assert len(pos) == sum(1 for t, i in kept if i == n)


def _composite_cpu_and_reference(d: dict[str, torch.Tensor]) -> list[tuple]:
    """(feats, alpha, gradients of a weighted loss) in float64, from the CPU kernel (float32) and from the
    float64 reference."""
    outs = []
    for fn, dtype in ((rasterize_cpu, torch.float32), (rasterize_reference, torch.float64)):
        leaves = {
            k: d[k].to(dtype).clone().requires_grad_() for k in ("means2d", "conics", "feats", "opacities")
        }
        feats, alpha = fn(*leaves.values(), d["depths"].to(dtype), d["radii"], W, H)
        w = torch.linspace(0.5, 1.5, feats.numel(), dtype=dtype).reshape(feats.shape)
        ((feats * w).sum() + alpha.square().sum()).backward()
        grads = {k: v.grad.double() for k, v in leaves.items()}
        outs.append((feats.detach().double(), alpha.detach().double(), grads))
    return outs


def test_culled_binning_composites_like_the_reference(cpu_ext):
    (fc, ac, gc), (fr, ar, gr) = _composite_cpu_and_reference(_hard_2d_gaussians(300, 2))
    assert float(ar.sum()) > 100.0
    # float32 vs float64: a few pixels flip at the alpha = 1/255 threshold behind low transmittance (~1e-4);
    # a wrongly dropped tile would lose whole contributions (>= 1/255 of a feature)
    for cpu, ref in ((fc, fr), (ac, ar)):
        assert float((cpu - ref).abs().max()) < 5e-4
        assert float((cpu - ref).abs().mean()) < 1e-6
    for k in ("means2d", "conics", "feats", "opacities"):
        assert float((gc[k] - gr[k]).abs().max()) <= 5e-4 * float(gr[k].abs().max()), k


def test_binning_is_a_stable_depth_sort_independent_of_threads(cpu_ext):
    """Several cameras, enough Gaussians for several chunks per pass, depth ties: every tile lists its
    Gaussians by (depth, index), and the outputs are bit-identical for 1, 2 and 3 threads."""
    cams = [_hard_2d_gaussians(2500, seed) for seed in (3, 4, 5)]
    d = {k: torch.cat([c[k] for c in cams]) for k in cams[0]}
    d["opacities"] = torch.full_like(d["opacities"], 0.9)  # most Gaussians binned
    d["depths"] = torch.round(d["depths"] * 8.0) / 8.0  # 9 distinct depths: many ties
    threads = torch.get_num_threads()
    try:
        runs = []
        for nt in (1, 2, 3):
            torch.set_num_threads(nt)
            runs.append(_bin(cpu_ext, d))
    finally:
        torch.set_num_threads(threads)
    for run in runs[1:]:
        for a, b in zip(runs[0], run, strict=True):
            assert torch.equal(a, b)

    _, toff, gid, goff, gpos = (t.numpy() for t in runs[0])
    n = d["depths"].shape[1]
    tx, ty = tile_grid(W, H)
    assert goff[-1] == len(gid) == toff[-1]
    for c in range(len(cams)):
        depth = d["depths"][c].numpy()
        expected: dict[int, list[int]] = {}
        for i in range(n):  # each Gaussian's own tiles, from its intersection list
            for p in gpos[goff[c * n + i] : goff[c * n + i + 1]]:
                tile = int(np.searchsorted(toff, p, side="right") - 1) - c * tx * ty
                expected.setdefault(tile, []).append(i)
        for t in range(tx * ty):
            ids = gid[toff[c * tx * ty + t] : toff[c * tx * ty + t + 1]].tolist()
            assert ids == sorted(expected.get(t, []), key=lambda i: (depth[i], i)), (c, t)


def _boundary_2d_gaussians(n: int, seed: int) -> dict[str, torch.Tensor]:
    """Small Gaussians (0.3-3 px) centred within a few pixels of the middle of a tile row or of a tile
    edge: their reach ends on either side of the boundary between the two 8-pixel halves the kernels
    evaluate separately."""
    gen = torch.Generator().manual_seed(seed)

    def u(*shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=gen, dtype=torch.float64)

    tile_x = torch.randint(0, W // TILE, (n,), generator=gen).double() * TILE
    offset = torch.where(u(n) < 0.7, 8.0, 0.0) + (u(n) - 0.5) * 8.0  # around x0 + 8 or x0
    means = torch.stack([tile_x + offset, u(n) * H], -1)
    theta = u(n) * math.pi
    s1 = 0.3 + u(n) * 2.7
    s2 = s1 * (0.3 + 0.7 * u(n))
    return {
        "means2d": means.float()[None],
        "conics": _conics(theta, s1, s2).float()[None],
        "feats": u(n, 4).float()[None],
        "opacities": (0.004 + 0.9 * u(n)).float()[None],
        "depths": (1.0 + u(n)).float()[None],
        "radii": torch.ceil(3.0 * s1).to(torch.int32)[None],
    }


def test_half_rows_lose_no_contribution_at_their_boundary(cpu_ext):
    """The compositing loops evaluate only the 8-pixel halves of a tile row that a Gaussian can reach: a
    half skipped wrongly would drop contributions >= 1/255 at pixels 7 and 8 (or 15 and 0) of a tile."""
    (fc, ac, gc), (fr, ar, gr) = _composite_cpu_and_reference(_boundary_2d_gaussians(600, 4))
    cols = torch.arange(W) % TILE
    at_boundary = (cols == 7) | (cols == 8) | (cols == 0) | (cols == 15)
    assert float(ar[0, :, at_boundary].sum()) > 50.0  # the boundary columns are well covered
    for cpu, ref in ((fc, fr), (ac, ar)):
        assert float((cpu - ref).abs().max()) < 5e-4
    for k in ("means2d", "conics", "feats", "opacities"):
        assert float((gc[k] - gr[k]).abs().max()) <= 5e-4 * float(gr[k].abs().max()), k
