"""Compressed splat formats of the final model, beside the INRIA ``.ply`` (go_core.ply):

* ``spz``: Niantic's ``.spz`` (version 2, gzip), ~10x smaller than the ``.ply``, SH kept (formats.spz);
* ``splat``: antimatter15's ``.splat``, 32 bytes a Gaussian, no view-dependent colour (go_core.formats.splat);
* ``compressed_ply``: PlayCanvas SuperSplat's ``.compressed.ply``, 256-Gaussian chunks with per-chunk bounds
  (go_core.formats.compressed_ply).

Each writer is a pure function ``Gaussians -> bytes``; the layouts follow the formats' published specs and
are read back by independent readers in the tests (npm ``spz-js`` for ``.spz`` and ``.compressed.ply``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from go_core.gaussians import Gaussians

# format name (export.formats) -> file name in the export step's folder and in outputs/
FILE_NAMES = {
    "ply": "point_cloud.ply",
    "spz": "model.spz",
    "splat": "model.splat",
    "compressed_ply": "model.compressed.ply",
}


def encode(g: Gaussians, fmt: str) -> bytes:
    """``g`` in the compressed format ``fmt`` (spz, splat, compressed_ply)."""
    if fmt == "spz":
        from go_core.formats.spz import encode_spz

        return encode_spz(g)
    if fmt == "splat":
        from go_core.formats.splat import encode_splat

        return encode_splat(g)
    if fmt == "compressed_ply":
        from go_core.formats.compressed_ply import encode_compressed_ply

        return encode_compressed_ply(g)
    raise ValueError(f"unknown splat format {fmt!r} (known: {', '.join(FILE_NAMES)})")


def write(g: Gaussians, fmt: str, folder: str | Path) -> Path:
    """Write ``g`` as ``fmt`` into ``folder`` under its file name (atomically); returns the path."""
    from go_core.io.atomic import atomic_write_bytes

    return atomic_write_bytes(Path(folder) / FILE_NAMES[fmt], encode(g, fmt))
