"""PlayCanvas SuperSplat's compressed ``.ply``: Gaussians in chunks of 256 with per-chunk bounds.

Elements (binary little-endian):

    chunk   (ceil(N / 256))  float min_x min_y min_z max_x max_y max_z, min_scale_x..z, max_scale_x..z,
                             min_r min_g min_b, max_r max_g max_b
    vertex  (N)              uint packed_position (11-10-11 bits of x, y, z within the chunk's bounds),
                             uint packed_rotation (2 bits: index of the largest of (w, x, y, z); 3 x 10 bits:
                             the others in order, q * sqrt(1/2) + 0.5, with the largest made positive),
                             uint packed_scale (11-10-11 of the log scales within the chunk's bounds),
                             uint packed_color (8-8-8-8: base colour 0.5 + SH_C0 * f_dc within the chunk's
                             colour bounds, then sigmoid(opacity))
    sh      (N, when SH)     uchar f_rest_0..(3·(K-1)-1), the INRIA channel-major order, (x / 8 + 0.5) * 255

Gaussians are ordered along a 3D Morton curve first (as SuperSplat does), so each chunk is compact in space.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from go_core.formats._arrays import byte_field, to_arrays

if TYPE_CHECKING:
    from go_core.gaussians import Gaussians

CHUNK = 256
CHUNK_PROPERTIES = [
    *(f"min_{c}" for c in "xyz"),
    *(f"max_{c}" for c in "xyz"),
    *(f"min_scale_{c}" for c in "xyz"),
    *(f"max_scale_{c}" for c in "xyz"),
    *(f"min_{c}" for c in "rgb"),
    *(f"max_{c}" for c in "rgb"),
]
VERTEX_PROPERTIES = ["packed_position", "packed_rotation", "packed_scale", "packed_color"]


def morton_order(points: np.ndarray, bits: int = 10) -> np.ndarray:
    """Indices sorting ``points`` [N, 3] along a 3D Morton (Z-order) curve of their bounding box."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    cells = ((points - lo) / np.maximum(hi - lo, 1e-12) * ((1 << bits) - 1)).round().astype(np.uint64)
    code = np.zeros(len(points), np.uint64)
    for b in range(bits):
        for axis in range(3):
            code |= ((cells[:, axis] >> np.uint64(b)) & np.uint64(1)) << np.uint64(3 * b + axis)
    return np.argsort(code, kind="stable")


def _unorm(x: np.ndarray, bits: int) -> np.ndarray:
    top = (1 << bits) - 1
    return np.clip(np.round(x * top), 0, top).astype(np.uint32)


def _normalise(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    span = hi - lo
    return np.where(span > 0, (x - lo) / np.where(span > 0, span, 1.0), 0.0)


def _pack_111011(v: np.ndarray) -> np.ndarray:
    return (_unorm(v[:, 0], 11) << 21) | (_unorm(v[:, 1], 10) << 11) | _unorm(v[:, 2], 11)


def pack_rotations(q_wxyz: np.ndarray) -> np.ndarray:
    """Smallest-three quaternions: 2 bits of the largest component's index, 3 x 10 bits of the others."""
    largest = np.abs(q_wxyz).argmax(axis=1)
    q = np.where(np.take_along_axis(q_wxyz, largest[:, None], 1) < 0, -q_wxyz, q_wxyz)
    others = np.array([[j for j in range(4) if j != k] for k in range(4)])[largest]  # [N, 3], in order
    v = _unorm(np.take_along_axis(q, others, 1) * np.sqrt(0.5) + 0.5, 10)
    return (largest.astype(np.uint32) << 30) | (v[:, 0] << 20) | (v[:, 1] << 10) | v[:, 2]


def _chunk_bounds(x: np.ndarray, n_chunks: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-chunk min / max of ``x`` [N, C] and their per-row copies."""
    pad = n_chunks * CHUNK - len(x)
    filled = np.concatenate([x, np.repeat(x[-1:], pad, axis=0)]) if pad else x
    blocks = filled.reshape(n_chunks, CHUNK, -1)
    lo, hi = blocks.min(axis=1), blocks.max(axis=1)
    rows = np.arange(len(x)) // CHUNK
    return lo, hi, lo[rows], hi[rows]


def encode_compressed_ply(g: Gaussians) -> bytes:
    """``g`` as SuperSplat compressed ``.ply`` bytes."""
    from go_core.gaussians import SH_C0

    a = to_arrays(g)
    order = morton_order(a.means)
    n, n_chunks = len(order), -(-len(order) // CHUNK)
    means, log_scales = a.means[order], np.clip(a.log_scales[order], -20.0, 20.0)
    colour = 0.5 + SH_C0 * a.sh_dc[order]
    p_lo, p_hi, p_rlo, p_rhi = _chunk_bounds(means, n_chunks)
    s_lo, s_hi, s_rlo, s_rhi = _chunk_bounds(log_scales, n_chunks)
    c_lo, c_hi, c_rlo, c_rhi = _chunk_bounds(colour, n_chunks)
    colour_n = _normalise(colour, c_rlo, c_rhi)
    packed_colour = (
        (_unorm(colour_n[:, 0], 8) << 24)
        | (_unorm(colour_n[:, 1], 8) << 16)
        | (_unorm(colour_n[:, 2], 8) << 8)
        | _unorm(a.opacity[order], 8)
    )
    vertex = np.stack(
        [
            _pack_111011(_normalise(means, p_rlo, p_rhi)),
            pack_rotations(a.quats_wxyz[order]),
            _pack_111011(_normalise(log_scales, s_rlo, s_rhi)),
            packed_colour,
        ],
        axis=1,
    ).astype("<u4")
    chunks = np.concatenate([p_lo, p_hi, s_lo, s_hi, c_lo, c_hi], axis=1).astype("<f4")
    rest = a.sh_rest[order].transpose(0, 2, 1).reshape(n, -1)  # channel-major, as the INRIA f_rest
    header = ["ply", "format binary_little_endian 1.0", f"element chunk {n_chunks}"]
    header += [f"property float {p}" for p in CHUNK_PROPERTIES]
    header += [f"element vertex {n}"] + [f"property uint {p}" for p in VERTEX_PROPERTIES]
    if rest.shape[1]:
        header += [f"element sh {n}"] + [f"property uchar f_rest_{i}" for i in range(rest.shape[1])]
    body = chunks.tobytes() + vertex.tobytes()
    if rest.shape[1]:
        body += byte_field((rest / 8.0 + 0.5) * 255.0).tobytes()
    return ("\n".join(header) + "\nend_header\n").encode("ascii") + body
