"""The Gaussians as float32 numpy arrays in the splat formats' shared conventions."""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from go_core.gaussians import Gaussians


class SplatArrays(NamedTuple):
    means: np.ndarray  # [N, 3]
    log_scales: np.ndarray  # [N, 3]
    quats_wxyz: np.ndarray  # [N, 4], unit length, w >= 0
    opacity: np.ndarray  # [N] in (0, 1)
    sh_dc: np.ndarray  # [N, 3]
    sh_rest: np.ndarray  # [N, K-1, 3] (coefficient-major, channel inner)


def to_arrays(g: Gaussians) -> SplatArrays:
    """Activated, normalised numpy copies of ``g`` (quaternions with w >= 0: q and -q are one rotation)."""
    g = g.detach().to(device="cpu")
    q = g.normalized_quats().double().numpy()
    q = np.where(q[:, :1] < 0, -q, q)
    sh = g.sh.double().numpy()
    return SplatArrays(
        means=g.means.double().numpy(),
        log_scales=g.log_scales.double().numpy(),
        quats_wxyz=q,
        opacity=g.opacities().double().numpy().reshape(-1),
        sh_dc=sh[:, 0, :],
        sh_rest=sh[:, 1:, :],
    )


def byte_field(x: np.ndarray) -> np.ndarray:
    """Values already on a 0..255 scale as the formats' byte fields: rounded, clamped to 0..255."""
    return np.clip(np.round(x), 0, 255).astype(np.uint8)
