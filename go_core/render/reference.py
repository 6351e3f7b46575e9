"""Pure-torch reference rasterizer (autograd; any dtype, float64 for finite-difference tests).

Slow but obviously correct, used as the ground truth for the compiled backend. It implements exactly the
compositing rules of docs/rendering.md: 16x16 tiles, per-tile front-to-back depth order, α = min(0.99,
o·exp(-σ)), contributions with α < 1/255 skipped, a pixel stops before the Gaussian that would bring its
transmittance to ≤ 1e-4. Work is split into chunks of tile rows, each under ``torch.utils.checkpoint`` so
the memory held for the backward pass is the inputs plus one chunk, not every Gaussian-pixel pair.
"""

from __future__ import annotations

import torch
from torch.utils.checkpoint import checkpoint

from go_core.render.tiles import TILE, bin_gaussians

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_STOP = 1e-4
CHUNK_ELEMS = 1 << 21  # Gaussian-pixel pairs evaluated per chunk


def _pixel_alphas(
    means2d: torch.Tensor, conics: torch.Tensor, opacities: torch.Tensor, units: tuple
) -> torch.Tensor:
    """[U,16,L] alpha of each listed Gaussian at each pixel of U rows of 16 pixels (0 where unused);
    ``units`` = (gidx, gvalid, px0, py) as for ``_composite_units``."""
    gidx, gvalid, px0, py = units
    dt = means2d.dtype
    m = means2d[gidx]  # [U,L,2]
    con = conics[gidx]
    op = opacities[gidx]
    cols = torch.arange(TILE, dtype=dt, device=m.device)
    px = (px0.to(dt)[:, None] + cols[None, :] + 0.5)[:, :, None]  # [U,16,1]
    pyc = (py.to(dt) + 0.5)[:, None, None]  # [U,1,1]
    dx = m[:, None, :, 0] - px  # [U,16,L]
    dy = m[:, None, :, 1] - pyc
    a, b, c = con[:, None, :, 0], con[:, None, :, 1], con[:, None, :, 2]
    sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
    sigma_safe = torch.clamp_min(sigma, 0.0)
    alpha = torch.clamp_max(op[:, None, :] * torch.exp(-sigma_safe), ALPHA_MAX)
    use = gvalid[:, None, :] & (sigma >= 0) & (alpha >= ALPHA_MIN)
    return torch.where(use, alpha, torch.zeros_like(alpha))


def _composite_units(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    feats: torch.Tensor,
    opacities: torch.Tensor,
    gidx: torch.Tensor,
    gvalid: torch.Tensor,
    px0: torch.Tensor,
    py: torch.Tensor,
) -> torch.Tensor:
    """Composite U rows of 16 pixels against their tile's Gaussian list.

    gidx/gvalid [U,L] (Gaussian index, real entry), px0 [U] first pixel column, py [U] pixel row.
    Returns [U,16,F+1]: accumulated features then alpha.
    """
    alpha = _pixel_alphas(means2d, conics, opacities, (gidx, gvalid, px0, py))
    f = feats[gidx]  # [U,L,F]
    trans_after = torch.cumprod(1.0 - alpha, dim=-1)
    keep = (trans_after > T_STOP).detach()
    trans_before = torch.cat([torch.ones_like(trans_after[..., :1]), trans_after[..., :-1]], dim=-1)
    w = torch.where(keep, alpha * trans_before, torch.zeros_like(alpha))  # [U,16,L]
    acc = torch.einsum("upl,ulf->upf", w, f)
    return torch.cat([acc, w.sum(-1, keepdim=True)], dim=-1)


def _chunks(counts: list[int], budget: int) -> list[list[tuple[int, int, int]]]:
    """Group (tile, row0, row1) units so that rows·16·L ≤ budget per chunk (L = max list length)."""
    out: list[list[tuple[int, int, int]]] = []
    cur: list[tuple[int, int, int]] = []
    cur_max = 0
    for t, n in enumerate(counts):
        n1 = max(n, 1)
        if TILE * TILE * n1 > budget:  # a crowded tile: split its rows
            if cur:
                out.append(cur)
                cur, cur_max = [], 0
            rows = max(1, budget // (TILE * n1))
            for r0 in range(0, TILE, rows):
                out.append([(t, r0, min(TILE, r0 + rows))])
            continue
        new_max = max(cur_max, n1)
        if cur and (len(cur) + 1) * TILE * TILE * new_max > budget:
            out.append(cur)
            cur, new_max = [], n1
        cur.append((t, 0, TILE))
        cur_max = new_max
    if cur:
        out.append(cur)
    return out


def rasterize_reference(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    feats: torch.Tensor,
    opacities: torch.Tensor,
    depths: torch.Tensor,
    radii: torch.Tensor,
    width: int,
    height: int,
    chunk_elems: int = CHUNK_ELEMS,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Composite C cameras: inputs [C,N,...] → (features [C,H,W,F], alpha [C,H,W,1])."""
    C = means2d.shape[0]
    F = feats.shape[-1]
    feats_out, alphas_out = [], []
    for ci in range(C):
        bins = bin_gaussians(means2d[ci], depths[ci], radii[ci], width, height)
        if bins.gauss_ids.numel() == 0:  # nothing visible: zeros, still connected to the graph
            link = sum(t[ci].sum() for t in (means2d, conics, feats, opacities)) * 0
            img = means2d.new_zeros(height, width, F + 1) + link
            feats_out.append(img[..., :F])
            alphas_out.append(img[..., F:])
            continue
        offsets = bins.offsets.tolist()
        counts = [offsets[i + 1] - offsets[i] for i in range(len(offsets) - 1)]
        parts = []
        for chunk in _chunks(counts, chunk_elems):
            L = max(1, max(counts[t] for t, _, _ in chunk))
            tiles = torch.tensor([t for t, r0, r1 in chunk for _ in range(r0, r1)], dtype=torch.int64)
            rows = torch.tensor([r for _, r0, r1 in chunk for r in range(r0, r1)], dtype=torch.int64)
            start = bins.offsets[tiles]
            n = bins.offsets[tiles + 1] - start
            ar = torch.arange(L, dtype=torch.int64)
            gvalid = ar[None, :] < n[:, None]
            pos = torch.where(
                gvalid, start[:, None] + ar[None, :], torch.zeros_like(gvalid, dtype=torch.int64)
            )
            gidx = bins.gauss_ids[pos]
            gidx = torch.where(gvalid, gidx, torch.zeros_like(gidx))
            px0 = (tiles % bins.tiles_x) * TILE
            py = (tiles // bins.tiles_x) * TILE + rows
            dev = means2d.device
            args = (means2d[ci], conics[ci], feats[ci], opacities[ci])
            idx = (gidx.to(dev), gvalid.to(dev), px0.to(dev), py.to(dev))
            if torch.is_grad_enabled() and any(t.requires_grad for t in args):
                parts.append(checkpoint(_composite_units, *args, *idx, use_reentrant=False))
            else:
                parts.append(_composite_units(*args, *idx))
        img = torch.cat(parts, 0)  # [tiles*16, 16, F+1] in (tile, row) order
        img = img.reshape(bins.tiles_y, bins.tiles_x, TILE, TILE, F + 1).permute(0, 2, 1, 3, 4)
        img = img.reshape(bins.tiles_y * TILE, bins.tiles_x * TILE, F + 1)[:height, :width]
        feats_out.append(img[..., :F])
        alphas_out.append(img[..., F:])
    return torch.stack(feats_out), torch.stack(alphas_out)


def median_depth_reference(proj, width: int, height: int, level: float = 0.5) -> torch.Tensor:
    """[C,H,W] median depth of projected Gaussians ``proj`` (go_core.render.projection.Projected), no
    gradient: per pixel the depth of the first Gaussian, front to back in its tile's list, after which the
    accumulated opacity 1 − T reaches ``level``; NaN where it never does."""
    means2d, conics, opacities, depths, radii = (
        proj.means2d, proj.conics, proj.opacities, proj.depths, proj.radii
    )  # fmt: skip
    C = means2d.shape[0]
    out = torch.full((C, height, width), float("nan"), dtype=means2d.dtype)
    rows = torch.arange(TILE, dtype=torch.int64)
    with torch.no_grad():
        for ci in range(C):
            bins = bin_gaussians(means2d[ci], depths[ci], radii[ci], width, height)
            offsets = bins.offsets.tolist()
            for t in range(len(offsets) - 1):
                if offsets[t + 1] == offsets[t]:
                    continue
                ids = bins.gauss_ids[offsets[t] : offsets[t + 1]]
                gidx = ids[None, :].expand(TILE, -1)
                x0, y0 = (t % bins.tiles_x) * TILE, (t // bins.tiles_x) * TILE
                units = (gidx, torch.ones_like(gidx, dtype=torch.bool), torch.full((TILE,), x0), y0 + rows)
                alpha = _pixel_alphas(means2d[ci], conics[ci], opacities[ci], units)  # [16 rows, 16 cols, L]
                crossed = torch.cumprod(1.0 - alpha, dim=-1) <= 1.0 - level
                first = torch.argmax(crossed.to(torch.int8), dim=-1)
                tile = torch.where(crossed.any(-1), depths[ci][ids][first], float("nan"))
                h, w = min(TILE, height - y0), min(TILE, width - x0)
                out[ci, y0 : y0 + h, x0 : x0 + w] = tile[:h, :w]
    return out
