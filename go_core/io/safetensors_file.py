"""Byte-reproducible safetensors files: the one writer every step, checkpoint and weight converter uses.

safetensors keeps a file's ``__metadata__`` in a Rust ``HashMap``, so a metadata dict with more than one key
is serialised in a different order in every process: the same tensors and metadata gave different bytes on
each run (the ``lora`` step's ``compact.safetensors`` alternated between hashes, which broke byte-identical
resumes). ``safetensors_bytes`` rewrites the header canonically (metadata and tensor entries sorted by key,
compact JSON, space-padded to 8 bytes as the format asks) and keeps the data buffer as the library laid it
out; any safetensors reader loads the result.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from go_core.io.atomic import atomic_write_bytes

_LENGTH = struct.Struct("<Q")
_ALIGN = 8


def _library_bytes(tensors: Mapping[str, Any], metadata: dict[str, str] | None) -> bytes:
    """The library's serialisation (torch tensors or numpy arrays, not mixed)."""
    import numpy as np

    values = list(tensors.values())
    if values and all(isinstance(v, np.ndarray) for v in values):
        from safetensors.numpy import save

        return save(dict(tensors), metadata=metadata)
    from safetensors.torch import save

    return save({k: v.contiguous() for k, v in tensors.items()}, metadata=metadata)


def canonical_header(raw: bytes) -> bytes:
    """``raw`` (a complete safetensors file) with its header re-serialised in a fixed order."""
    (n,) = _LENGTH.unpack_from(raw)
    header = json.loads(raw[_LENGTH.size : _LENGTH.size + n])
    meta = header.pop("__metadata__", None)
    ordered: dict[str, Any] = {"__metadata__": dict(sorted(meta.items()))} if meta else {}
    ordered.update(sorted(header.items()))
    text = json.dumps(ordered, separators=(",", ":"), ensure_ascii=False).encode("utf-8")
    text += b" " * (-(_LENGTH.size + len(text)) % _ALIGN)
    return _LENGTH.pack(len(text)) + text + raw[_LENGTH.size + n :]


def safetensors_bytes(tensors: Mapping[str, Any], metadata: dict[str, str] | None = None) -> bytes:
    """The bytes of a safetensors file holding ``tensors``: identical for equal inputs in any process."""
    return canonical_header(_library_bytes(tensors, metadata))


def write_safetensors(
    path: str | Path, tensors: Mapping[str, Any], metadata: dict[str, str] | None = None
) -> Path:
    """Write ``tensors`` (+ string ``metadata``) to ``path`` atomically and byte-reproducibly."""
    return atomic_write_bytes(path, safetensors_bytes(tensors, metadata))
