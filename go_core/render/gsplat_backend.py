"""CUDA backend: gsplat's ``rasterization`` behind our render() contract (gsplat is an optional dependency).

Mapping: render_mode "RGB+ED" gives RGB and the expected depth (accumulated depth / alpha, the same
definition as ours); ``packed=False`` so ``meta["means2d"]`` is dense [C,N,2] and its ``.grad`` is the
screen-space gradient; ``meta["radii"]`` is [C,N] (gsplat < 1.5) or per-axis [C,N,2] (gsplat ≥ 1.5, reduced
here with max). The background is applied by go_core.render.api for every backend, so none is passed.

Known differences to the CPU/reference backends (documented in docs/rendering.md): gsplat clamps alpha at
0.999 (we use 0.99) and gsplat ≥ 1.5 bounds each Gaussian by per-axis, opacity-aware extents, so faint
contributions (alpha near 1/255) beyond those extents can differ. Images agree to ~1e-3 on average.
"""

from __future__ import annotations

import torch

from go_core.render.types import RenderOutput


def gsplat_available() -> bool:
    try:
        import gsplat  # noqa: F401
    except Exception:
        return False
    return torch.cuda.is_available()


def render_gsplat(
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
):
    """Render with gsplat on CUDA tensors; returns go_core.render.RenderOutput."""

    try:
        from gsplat import rasterization
    except ImportError as exc:
        raise RuntimeError(
            "backend='cuda' needs gsplat (pip install 'go-pipeline[cuda]'); use backend='cpu' otherwise"
        ) from exc
    if means.device.type != "cuda":
        raise ValueError(f"backend='cuda' needs CUDA tensors, got {means.device}")
    if means.shape[0] == 0:  # gsplat does not accept empty inputs
        C = viewmats.shape[0]
        z = means.new_zeros(C, height, width, 1)
        return RenderOutput(
            z.expand(C, height, width, 3).clone(),
            z,
            z.clone(),
            means.new_zeros(C, 0, 2),
            torch.zeros(C, 0, dtype=torch.int32, device=means.device),
        )
    rgbd, alpha, meta = rasterization(
        means,
        quats,
        scales,
        opacities,
        colors,
        viewmats,
        Ks,
        int(width),
        int(height),
        near_plane=near_plane,
        far_plane=far_plane,
        eps2d=0.3,
        sh_degree=sh_degree,
        packed=False,
        tile_size=16,
        render_mode="RGB+ED",
        rasterize_mode="antialiased" if antialiased else "classic",
    )
    radii = meta["radii"]
    if radii.dim() == 3:  # gsplat >= 1.5: per-axis radii
        radii = radii.max(dim=-1).values
    return RenderOutput(rgbd[..., :3], alpha, rgbd[..., 3:4], meta["means2d"], radii.to(torch.int32))
