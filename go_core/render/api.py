"""Backend dispatch for the rendering API (contract: go_core.render; maths: docs/rendering.md)."""

from __future__ import annotations

import warnings

import torch

from go_core.render.types import RenderOutput

BACKENDS = ("auto", "cpu", "cuda", "reference")
DEPTH_EPS = 1e-10
__all__ = [
    "BACKENDS",
    "DEPTH_EPS",
    "RenderOutput",
    "render",
    "render_camera",
    "render_gaussians",
    "render_median_depth",
]


def _check_inputs(means, quats, scales, opacities, colors, viewmats, Ks, width, height) -> None:
    n = means.shape[0]
    if means.dim() != 2 or means.shape[1] != 3:
        raise ValueError(f"means must be [N,3], got {tuple(means.shape)}")
    for name, t, shape in (
        ("quats", quats, (n, 4)),
        ("scales", scales, (n, 3)),
        ("opacities", opacities, (n,)),
    ):
        if tuple(t.shape) != shape:
            raise ValueError(f"{name} must be {list(shape)}, got {tuple(t.shape)}")
    if colors.shape[0] != n:
        raise ValueError(f"colors must have N={n} rows, got {tuple(colors.shape)}")
    if viewmats.dim() != 3 or viewmats.shape[1:] != (4, 4):
        raise ValueError(f"viewmats must be [C,4,4], got {tuple(viewmats.shape)}")
    if Ks.shape != (viewmats.shape[0], 3, 3):
        raise ValueError(f"Ks must be [C,3,3] matching viewmats, got {tuple(Ks.shape)}")
    if int(width) <= 0 or int(height) <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")


def _resolve_backend(backend: str, device: torch.device) -> str:
    """Resolve "auto": gsplat for CUDA tensors, else the compiled CPU backend, or (warning) the reference
    when the extension cannot be built on this machine. An explicit "cpu" raises instead."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown render backend {backend!r}; choose one of {BACKENDS}")
    if backend != "auto":
        return backend
    if device.type == "cuda":
        return "cuda"
    from go_core.render.build import ExtensionBuildError, load_extension

    try:
        load_extension()
    except ExtensionBuildError as exc:
        warnings.warn(f"{exc}; falling back to the slow pure-torch reference renderer", stacklevel=3)
        return "reference"
    return "cpu"


def render(
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
    background: torch.Tensor | None = None,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    antialiased: bool = False,
    backend: str = "auto",
) -> RenderOutput:
    """Render N Gaussians into C cameras (contract in go_core.render)."""
    _check_inputs(means, quats, scales, opacities, colors, viewmats, Ks, width, height)
    width, height = int(width), int(height)
    kind = _resolve_backend(backend, means.device)
    args = (means, quats, scales, opacities, colors, viewmats, Ks, width, height)
    options = dict(sh_degree=sh_degree, near_plane=near_plane, far_plane=far_plane, antialiased=antialiased)
    if kind == "cuda":
        from go_core.render.gsplat_backend import render_gsplat

        out = render_gsplat(*args, **options)
    else:
        if kind == "reference":
            from go_core.render.projection import project_gaussians as project
        else:
            if means.device.type != "cpu":
                raise ValueError(f"backend='cpu' needs CPU tensors, got {means.device}")
            from go_core.render.cpu import project_cpu as project
        proj = project(*args, **options)
        if kind == "reference":
            from go_core.render.reference import rasterize_reference

            feats = torch.cat([proj.colors, proj.depths[..., None]], dim=-1)  # depth as a 4th channel
            acc, alpha = rasterize_reference(
                proj.means2d, proj.conics, feats, proj.opacities, proj.depths, proj.radii, width, height
            )
        else:
            from go_core.render.cpu import rasterize_cpu_with_depth

            acc, alpha = rasterize_cpu_with_depth(
                proj.means2d, proj.conics, proj.colors, proj.opacities, proj.depths, proj.radii, width, height
            )
        if kind == "cpu" and not (background is not None and background.requires_grad):
            from go_core.render.cpu import finish_cpu

            rgb, depth, alpha = finish_cpu(acc, alpha, background, DEPTH_EPS)
            return RenderOutput(rgb, alpha, depth, proj.means2d, proj.radii)
        depth = acc[..., 3:4] / torch.clamp_min(alpha, DEPTH_EPS)
        out = RenderOutput(acc[..., :3], alpha, depth, proj.means2d, proj.radii)
    if background is not None:
        bg = background.to(out.rgb.dtype)
        bg = bg.reshape(-1, 1, 1, 3) if bg.dim() == 2 else bg.reshape(1, 1, 1, 3)
        out.rgb = out.rgb + (1.0 - out.alpha) * bg
    return out


def render_gaussians(gaussians, viewmats, Ks, width, height, **kwargs) -> RenderOutput:
    """Render a ``go_core.gaussians.Gaussians`` set: applies the activations, then ``render``."""
    return render(
        gaussians.means,
        gaussians.quats,
        gaussians.scales(),
        gaussians.opacities(),
        gaussians.sh,
        viewmats,
        Ks,
        width,
        height,
        sh_degree=kwargs.pop("sh_degree", gaussians.sh_degree),
        **kwargs,
    )


def render_camera(gaussians, camera, **kwargs) -> RenderOutput:
    """Render a ``Gaussians`` set into one ``go_core.camera.Camera`` (a batch of C = 1, on the Gaussians'
    device); keyword arguments as for ``render``."""
    device = gaussians.means.device
    return render_gaussians(
        gaussians,
        camera.viewmat_tensor(device=device)[None],
        camera.K_tensor(device=device)[None],
        camera.width,
        camera.height,
        **kwargs,
    )


def render_median_depth(
    gaussians,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    *,
    level: float = 0.5,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    antialiased: bool = False,
    backend: str = "auto",
) -> torch.Tensor:
    """[C,H,W] median depth of a ``Gaussians`` set, no gradient: per pixel the camera depth of the Gaussian
    at which the accumulated opacity reaches ``level`` front to back (NaN where it never does;
    docs/rendering.md). Unlike the expected depth it does not average a translucent front with what lies
    behind it. gsplat has no equivalent: CUDA tensors are rendered by the compiled CPU backend on host
    copies."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"the median depth's opacity level must lie in (0, 1), got {level}")
    g = gaussians.to(device="cpu")
    kind = _resolve_backend("auto" if backend == "cuda" else backend, torch.device("cpu"))
    args = (g.means, g.quats, g.scales(), g.opacities(), g.means.new_zeros(len(g.means), 3))
    args += (viewmats.cpu(), Ks.cpu(), int(width), int(height))
    options = dict(near_plane=near_plane, far_plane=far_plane, antialiased=antialiased)
    with torch.no_grad():
        if kind == "reference":
            from go_core.render.projection import project_gaussians
            from go_core.render.reference import median_depth_reference

            p = project_gaussians(*args, **options)
            median = median_depth_reference
        else:
            from go_core.render.cpu import median_depth_cpu, project_cpu

            p = project_cpu(*args, **options)
            median = median_depth_cpu
        return median(p, width, height, level)
