"""antimatter15's ``.splat``: 32 bytes a Gaussian, no header, no view-dependent colour.

Per Gaussian (little-endian): position 3 x float32, scale 3 x float32 (linear, exp of the log scale),
colour 4 x uint8 (RGB = (0.5 + SH_C0 * f_dc) * 255, A = sigmoid(opacity) * 255), rotation 4 x uint8
(w, x, y, z of the unit quaternion, q * 128 + 128). Rows sorted by size x opacity, largest first (as the
format's converter does, so that a streaming viewer shows the big Gaussians first).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from go_core.formats._arrays import byte_field, to_arrays

if TYPE_CHECKING:
    from go_core.gaussians import Gaussians

ROW_BYTES = 32
SPLAT_DTYPE = np.dtype([("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])


def encode_splat(g: Gaussians) -> bytes:
    """``g`` as ``.splat`` bytes."""
    from go_core.gaussians import SH_C0

    a = to_arrays(g)
    order = np.argsort(-(np.exp(a.log_scales.sum(axis=1)) * a.opacity), kind="stable")
    rows = np.zeros(len(order), SPLAT_DTYPE)
    rows["position"] = a.means[order]
    rows["scale"] = np.exp(a.log_scales[order])
    rgb = (0.5 + SH_C0 * a.sh_dc[order]) * 255.0
    rows["rgba"] = byte_field(np.concatenate([rgb, a.opacity[order, None] * 255.0], axis=1))
    rows["rot"] = byte_field(a.quats_wxyz[order] * 128.0 + 128.0)
    return rows.tobytes()


def decode_splat(data: bytes) -> np.ndarray:
    """The rows of ``.splat`` bytes as a structured array (the format is its own layout: no header)."""
    if len(data) % ROW_BYTES:
        raise ValueError(f".splat data of {len(data)} bytes is not a whole number of {ROW_BYTES}-byte rows")
    return np.frombuffer(data, SPLAT_DTYPE)
