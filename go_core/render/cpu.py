"""Compiled CPU backend: C++/OpenMP projection and tile rasterizer wrapped in torch.autograd.Functions.

Two Functions, so that ``means2d`` (output of the projection, input of the rasterizer) is a real non-leaf
tensor whose ``.grad`` the densifier can read. Both compute in float32 (other dtypes are converted and the
gradients converted back); both are deterministic across runs and thread counts.
"""

from __future__ import annotations

import torch

from go_core.render.build import load_extension
from go_core.render.projection import EPS2D, Projected, check_colors
from go_core.render.reference import T_STOP
from go_core.render.tiles import TILE, tile_grid


def _f32(t: torch.Tensor) -> torch.Tensor:
    return t.detach().to(torch.float32).contiguous()


class _ProjectCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, opacities, colors, viewmats, Ks, settings):
        ext = load_extension()
        inputs = [_f32(t) for t in (means, quats, scales, opacities, colors, viewmats, Ks)]
        m2, con, col, op, dep, rad = ext.project_forward(*inputs, *settings)
        ctx.save_for_backward(*inputs)
        ctx.settings = settings
        ctx.dtypes = [t.dtype for t in (means, quats, scales, opacities, colors, viewmats)]
        ctx.mark_non_differentiable(rad)
        dt = means.dtype
        return m2.to(dt), con.to(dt), col.to(dt), op.to(dt), dep.to(dt), rad

    @staticmethod
    def backward(ctx, g_m2, g_con, g_col, g_op, g_dep, _g_rad):
        ext = load_extension()
        inputs = ctx.saved_tensors
        C, N = inputs[5].shape[0], inputs[0].shape[0]
        shapes = ((C, N, 2), (C, N, 3), (C, N, 3), (C, N), (C, N))
        grads = [
            _f32(g) if g is not None else torch.zeros(s)
            for g, s in zip((g_m2, g_con, g_col, g_op, g_dep), shapes, strict=True)
        ]
        out = ext.project_backward(*inputs, *ctx.settings, *grads, bool(ctx.needs_input_grad[5]))
        return (*[g.to(dt) for g, dt in zip(out, ctx.dtypes, strict=True)], None, None)


def project_cpu(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    *,
    sh_degree: int | None = None,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    antialiased: bool = False,
    eps2d: float = EPS2D,
) -> Projected:
    """Compiled equivalent of ``go_core.render.projection.project_gaussians``."""
    check_colors(colors, sh_degree)
    settings = (
        int(width),
        int(height),
        float(near_plane),
        float(far_plane),
        float(eps2d),
        bool(antialiased),
        -1 if sh_degree is None else int(sh_degree),
    )
    m2, con, col, op, dep, rad = _ProjectCPU.apply(
        means, quats, scales, opacities, colors, viewmats, Ks, settings
    )
    return Projected(m2, con, col, op, dep, rad)


class _RasterizeCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, colors, feat4, opacities, depths, radii, width, height):
        ext = load_extension()
        C, N = means2d.shape[:2]
        f32 = [_f32(t) for t in (means2d, conics, colors, feat4, opacities, depths)]
        rad = radii.detach().to(torch.int32).contiguous()
        params, toff, gid, goff, gpos = ext.bin_and_pack(*f32, rad, width, height)
        out, alpha, tfinal, stop = ext.rasterize_forward(params, toff, gid, C, N, width, height, T_STOP)
        ctx.save_for_backward(params, toff, gid, goff, gpos, tfinal, stop)
        ctx.meta = (C, N, width, height, means2d.dtype)
        return out.to(means2d.dtype), alpha.to(means2d.dtype)

    @staticmethod
    def backward(ctx, grad_out, grad_alpha):
        ext = load_extension()
        C, N, width, height, dtype = ctx.meta
        params, toff, gid, goff, gpos, tfinal, stop = ctx.saved_tensors
        if grad_out is None:
            grad_out = torch.zeros(C, height, width, 4)
        if grad_alpha is None:
            grad_alpha = torch.zeros(C, height, width, 1)
        grads = ext.rasterize_backward(
            params, toff, gid, goff, gpos, tfinal, stop, _f32(grad_out), _f32(grad_alpha), C, N, width, height
        )
        g_m, g_c, g_col, g_f4, g_o = (g.to(dtype) for g in grads)
        return g_m, g_c, g_col, g_f4, g_o, None, None, None, None


def _check_cpu(means2d: torch.Tensor) -> None:
    if means2d.device.type != "cpu":
        raise ValueError(f"backend='cpu' needs CPU tensors, got {means2d.device}")


def rasterize_cpu(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    feats: torch.Tensor,
    opacities: torch.Tensor,
    depths: torch.Tensor,
    radii: torch.Tensor,
    width: int,
    height: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Composite C cameras: [C,N,...] inputs (feats [C,N,4]) → (feats [C,H,W,4], alpha [C,H,W,1])."""
    if feats.shape[-1] != 4:
        raise ValueError(f"the CPU rasterizer composites 4 channels (RGB + depth), got {feats.shape[-1]}")
    _check_cpu(means2d)
    return _RasterizeCPU.apply(
        means2d, conics, feats[..., :3], feats[..., 3], opacities, depths, radii, int(width), int(height)
    )


def rasterize_cpu_with_depth(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    colors: torch.Tensor,
    opacities: torch.Tensor,
    depths: torch.Tensor,
    radii: torch.Tensor,
    width: int,
    height: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``rasterize_cpu`` with feats = [colors, depths] (the render's case), without building the [C,N,4]
    tensor: colours [C,N,3] and depths [C,N] go to the kernel as they are and get their gradients apart."""
    _check_cpu(means2d)
    return _RasterizeCPU.apply(
        means2d, conics, colors, depths, opacities, depths, radii, int(width), int(height)
    )


def median_depth_cpu(proj: Projected, width: int, height: int, level: float = 0.5) -> torch.Tensor:
    """Compiled ``go_core.render.reference.median_depth_reference`` ([C,H,W] float32, NaN where the opacity
    never reaches ``level``; no gradient): the forward compositing stopped at transmittance 1 − level, and
    the depth of the Gaussian each pixel stopped at."""
    means2d, conics, opacities, depths, radii = (
        proj.means2d, proj.conics, proj.opacities, proj.depths, proj.radii
    )  # fmt: skip
    _check_cpu(means2d)
    ext = load_extension()
    C, N = means2d.shape[:2]
    zeros = torch.zeros(C, N, 3)
    f32 = [_f32(t) for t in (means2d, conics, zeros, depths, opacities, depths)]
    rad = radii.detach().to(torch.int32).contiguous()
    params, toff, gid, _, _ = ext.bin_and_pack(*f32, rad, width, height)
    stop = ext.rasterize_forward(params, toff, gid, C, N, width, height, 1.0 - level)[3].long()
    if gid.numel() == 0:
        return torch.full((C, height, width), float("nan"))
    tiles_x, tiles_y = tile_grid(width, height)
    ys, xs = torch.arange(height) // TILE, torch.arange(width) // TILE
    tile = (torch.arange(C)[:, None, None] * tiles_y + ys[None, :, None]) * tiles_x + xs[None, None, :]
    start, count = toff[tile], toff[tile + 1] - toff[tile]
    stopped = stop < count
    gauss = gid.long()[(start + stop).masked_fill(~stopped, 0)]
    cam = torch.arange(C)[:, None, None].expand_as(gauss)
    return torch.where(stopped, f32[3][cam, gauss], float("nan"))


class _FinishCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, feats, alpha, background, eps):
        ctx.set_materialize_grads(False)
        ext = load_extension()
        f, a = _f32(feats), _f32(alpha)
        bg = background if background is not None else torch.empty(0)
        rgb, depth, alpha_out = ext.finish_forward(f, a, bg, eps)
        ctx.save_for_backward(f, a, bg)
        ctx.eps = eps
        ctx.dtype = feats.dtype
        return rgb.to(feats.dtype), depth.to(feats.dtype), alpha_out.to(feats.dtype)

    @staticmethod
    def backward(ctx, g_rgb, g_depth, g_alpha):
        f, a, bg = ctx.saved_tensors
        empty = torch.empty(0)
        if g_rgb is None:
            g_rgb = torch.zeros(f.shape[:-1] + (3,))
        g_f, g_a = load_extension().finish_backward(
            f,
            a,
            bg,
            ctx.eps,
            _f32(g_rgb),
            empty if g_depth is None else _f32(g_depth),
            empty if g_alpha is None else _f32(g_alpha),
        )
        return g_f.to(ctx.dtype), g_a.to(ctx.dtype), None, None


def finish_cpu(
    feats: torch.Tensor, alpha: torch.Tensor, background: torch.Tensor | None, depth_eps: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The rasterizer's [C,H,W,4] features (RGB + depth) and alpha → (rgb over ``background``, expected depth
    ``acc_d / max(alpha, depth_eps)``, alpha), as the API's torch code computes them, in one compiled pass
    each way. ``background``: None, [3] or [C,3], constant (no gradient)."""
    bg = None
    if background is not None:
        bg = _f32(background).reshape(-1, 3).expand(feats.shape[0], 3).contiguous()
    return _FinishCPU.apply(feats, alpha, bg, float(depth_eps))
