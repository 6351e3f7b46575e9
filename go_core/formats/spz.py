"""Niantic's ``.spz`` (version 2): a gzip stream of a 16-byte header and the Gaussians attribute by attribute.

Layout (little-endian; github.com/nianticlabs/spz, README "File Format"):

    header   magic 0x5053474e ("NGSP"), version 2, numPoints (3 x uint32), shDegree, fractionalBits, flags,
             reserved (4 x uint8)
    then, each for all points in turn:
    positions  3 x 24-bit signed fixed point, ``fractionalBits`` fractional bits
    alphas     uint8 sigmoid(opacity) * 255
    colors     3 x uint8 (f_dc * 0.15 + 0.5) * 255
    scales     3 x uint8 (log scale + 10) * 16
    rotations  3 x uint8 (x, y, z) * 127.5 + 127.5 of the unit quaternion with w >= 0 (w = sqrt(1 - |xyz|²))
    sh         (shDim x 3) uint8 per point, coefficient-major with the channel inner, x * 128 + 128, degree 1
               on a 5-bit grid and higher degrees on a 4-bit grid (the reference library's choice)

Coordinates: the format stores RUB (x right, y up, z back: OpenGL / three.js), the ``.ply`` and go-pipeline
use RDF (OpenCV), so the writer turns the model 180 degrees about x (``rdf_to_rub``: y and z negated, the
quaternion conjugated by that turn, the SH coefficients odd in y or z negated), as Niantic's converter does
for a ``.ply``. Quantisation steps: positions 2^-fractionalBits, log scales 1/16, colours (f_dc)
1/(0.15 * 255) = 0.026, opacity 1/255, quaternion components 1/127.5, SH 8/128 (degree 1) or 16/128.
"""

from __future__ import annotations

import gzip
import struct
from typing import TYPE_CHECKING

import numpy as np

from go_core.formats._arrays import SplatArrays, byte_field, to_arrays

if TYPE_CHECKING:
    from go_core.gaussians import Gaussians

MAGIC = 0x5053474E
VERSION = 2
FRACTIONAL_BITS = 12  # the reference library's default: 1/4096 units
COLOR_SCALE = 0.15
SH_BITS_DEGREE1 = 5
SH_BITS_REST = 4
MAX_SH_DEGREE = 3


def position_step(fractional_bits: int = FRACTIONAL_BITS) -> float:
    """The positions' quantisation step (a round trip errs by at most half of it)."""
    return 1.0 / (1 << fractional_bits)


def fractional_bits_for(means: np.ndarray) -> int:
    """The most fractional bits (at most 12) that keep every coordinate inside 24-bit signed range."""
    extent = float(np.abs(means).max(initial=0.0))
    bits = FRACTIONAL_BITS
    while bits > 0 and extent * (1 << bits) >= (1 << 23) - 1:
        bits -= 1
    if extent * (1 << bits) >= (1 << 23) - 1:
        raise ValueError(f"coordinates up to {extent:g} do not fit the 24-bit positions of .spz")
    return bits


# sign of each SH coefficient (degree 1..3, go_core.sh order) under (x, y, z) -> (x, -y, -z)
SH_FLIP_YZ = np.array([-1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, -1, 1, -1, 1], dtype=np.float64)
FLIP_YZ = np.array([1.0, -1.0, -1.0])


def rdf_to_rub(a: SplatArrays) -> SplatArrays:
    """The model turned 180 degrees about x: OpenCV (RDF) world <-> .spz's RUB (its own inverse)."""
    k = a.sh_rest.shape[1]
    return a._replace(
        means=a.means * FLIP_YZ,
        quats_wxyz=a.quats_wxyz * np.array([1.0, 1.0, -1.0, -1.0]),
        sh_rest=a.sh_rest * SH_FLIP_YZ[:k, None],
    )


def _quantize_sh(x: np.ndarray, bits: int) -> np.ndarray:
    bucket = 1 << (8 - bits)
    q = np.round(x * 128.0 + 128.0)
    q = np.floor((q + bucket / 2) / bucket) * bucket
    return np.clip(q, 0, 255).astype(np.uint8)


def encode_spz(g: Gaussians, sh_degree: int | None = None) -> bytes:
    """``g`` as ``.spz`` bytes (SH truncated to ``sh_degree``, default min(g's degree, 3))."""
    degree = min(g.sh_degree if sh_degree is None else sh_degree, MAX_SH_DEGREE)
    a = rdf_to_rub(to_arrays(g.with_sh_degree(degree)))
    n = a.means.shape[0]
    bits = fractional_bits_for(a.means)
    fixed = np.round(a.means * (1 << bits)).astype(np.int64).reshape(-1) & 0xFFFFFF
    positions = np.stack([fixed & 0xFF, (fixed >> 8) & 0xFF, (fixed >> 16) & 0xFF], axis=1).astype(np.uint8)
    alphas = byte_field(a.opacity * 255.0)
    colors = byte_field(a.sh_dc * (COLOR_SCALE * 255.0) + 0.5 * 255.0)
    scales = byte_field((a.log_scales + 10.0) * 16.0)
    rotations = byte_field(a.quats_wxyz[:, 1:] * 127.5 + 127.5)
    rest = a.sh_rest.reshape(n, -1)  # [N, (K-1)*3], coefficient-major, channel inner
    sh = np.concatenate(
        [_quantize_sh(rest[:, :9], SH_BITS_DEGREE1), _quantize_sh(rest[:, 9:], SH_BITS_REST)], axis=1
    )
    header = struct.pack("<IIIBBBB", MAGIC, VERSION, n, degree, bits, 0, 0)
    body = b"".join(x.tobytes() for x in (positions, alphas, colors, scales, rotations, sh))
    return gzip.compress(header + body, compresslevel=9, mtime=0)
