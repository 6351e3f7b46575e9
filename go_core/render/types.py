"""The rendering API's result type, shared by the dispatch (api.py) and every backend (no import cycle)."""

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
