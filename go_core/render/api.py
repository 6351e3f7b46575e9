"""Backend dispatch for the rendering API (see go_core.render for the contract)."""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class RenderOutput:
    """Per-camera images and what densification needs.

    rgb [C,H,W,3]; alpha [C,H,W,1]; depth [C,H,W,1] expected depth (Σ wᵢ zᵢ / max(alpha, eps));
    means2d [C,N,2] projected centres in pixels, a non-leaf tensor whose ``.grad`` (call ``retain_grad()``
    before backward) is the screen-space positional gradient; radii [C,N] int32 pixel radii, 0 = culled.
    """

    rgb: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    means2d: torch.Tensor
    radii: torch.Tensor


def render(*args, **kwargs) -> RenderOutput:  # replaced by the rasterizer work (issue #3)
    raise NotImplementedError("rasterizer backends are being written (issue #3)")


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
