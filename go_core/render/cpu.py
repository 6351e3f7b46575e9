"""Compiled CPU backend: C++/OpenMP tile rasterizer wrapped in a torch.autograd.Function.

Projection and SH stay in torch (go_core.render.projection); this module composites the projected
Gaussians. Inputs are float32 (other dtypes are computed in float32 and cast back).
"""

from __future__ import annotations

import torch

from go_core.render.build import load_extension


class _RasterizeCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, feats, opacities, depths, radii, width, height):
        ext = load_extension()
        C, N = means2d.shape[:2]
        f32 = [t.detach().to(torch.float32).contiguous() for t in (means2d, conics, feats, opacities, depths)]
        rad = radii.detach().to(torch.int32).contiguous()
        params, toff, gid, goff, gpos = ext.bin_and_pack(*f32, rad, width, height)
        out, alpha, tfinal, stop = ext.rasterize_forward(params, toff, gid, C, N, width, height)
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
        g_m, g_c, g_f, g_o = ext.rasterize_backward(
            params, toff, gid, goff, gpos, tfinal, stop,
            grad_out.to(torch.float32).contiguous(), grad_alpha.to(torch.float32).contiguous(),
            C, N, width, height,
        )
        return g_m.to(dtype), g_c.to(dtype), g_f.to(dtype), g_o.to(dtype), None, None, None, None


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
    if means2d.device.type != "cpu":
        raise ValueError(f"backend='cpu' needs CPU tensors, got {means2d.device}")
    return _RasterizeCPU.apply(means2d, conics, feats, opacities, depths, radii, int(width), int(height))
