"""Content hashes and cache keys.

* ``canonical_json``: the one JSON spelling hashed into keys (sorted keys, no spaces, exact floats).
* ``cache_key``: sha256 of the step name, its code (go_pipeline.codehash), an optional VERSION override,
  resolved params, seed and its inputs' content hashes.
* ``files_hash``: content hash of a set of files (relative name + bytes), used for artifacts and the scene.
* ``FileHashCache``: per-file sha256 remembered by (relative path, size, mtime_ns), so a no-op run over
  an unchanged scene folder only stats its files.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

_CHUNK = 1 << 20


def canonical_json(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def sha256_file(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def combine_file_hashes(file_hashes: dict[str, str]) -> str:
    """One hash for a set of (relative POSIX path, sha256) pairs; independent of listing order."""
    h = hashlib.sha256()
    for rel in sorted(file_hashes):
        h.update(rel.encode("utf-8") + b"\0" + file_hashes[rel].encode("ascii") + b"\n")
    return h.hexdigest()


def cache_key(
    step: str,
    version: str | None,
    params: dict[str, Any],
    seed: int,
    inputs: dict[str, str],
    code: str = "",
) -> str:
    """``inputs`` maps input name -> content hash of that input (an artifact or the scene folder);
    ``code`` is the digest of the source files the step runs; ``version`` the module's optional VERSION
    override (None when it defines none)."""
    material = {
        "step": step,
        "version": version,
        "code": code,
        "params": params,
        "seed": int(seed),
        "inputs": inputs,
    }
    return hashlib.sha256(canonical_json(material).encode("utf-8")).hexdigest()


def walk_files(root: Path, exclude: Iterable[Path] = ()) -> list[Path]:
    """Every regular file under ``root`` (following no symlinked folders), skipping the ``exclude`` dirs."""
    excluded = {os.path.realpath(p) for p in exclude}
    found: list[Path] = []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(
            d for d in dirnames if os.path.realpath(os.path.join(dirpath, d)) not in excluded
        )
        for name in filenames:
            p = Path(dirpath) / name
            if p.is_file():
                found.append(p)
    return found


class FileHashCache:
    """sha256 of files keyed by (relative path, size, mtime_ns); saved as JSON (atomically) on ``save``."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self._entries: dict[str, list] = {}
        self._dirty = False
        if path is not None and path.is_file():
            try:
                data = json.loads(path.read_text(encoding="utf-8"))
                if isinstance(data, dict):
                    self._entries = data
            except (OSError, ValueError):
                self._entries = {}  # a corrupt cache is only a cache

    def file_hash(self, path: Path, rel: str) -> str:
        st = path.stat()
        hit = self._entries.get(rel)
        if hit is not None and hit[0] == st.st_size and hit[1] == st.st_mtime_ns:
            return hit[2]
        digest = sha256_file(path)
        self._entries[rel] = [st.st_size, st.st_mtime_ns, digest]
        self._dirty = True
        return digest

    def save(self) -> None:
        if self.path is None or not self._dirty:
            return
        from go_core.io.atomic import atomic_write_text

        atomic_write_text(self.path, json.dumps(self._entries, sort_keys=True))
        self._dirty = False


def folder_hashes(
    root: Path, exclude: Iterable[Path] = (), cache: FileHashCache | None = None
) -> dict[str, str]:
    """{relative POSIX path: sha256} for every file under ``root`` except the ``exclude`` folders."""
    result: dict[str, str] = {}
    for p in walk_files(root, exclude):
        rel = p.relative_to(root).as_posix()
        result[rel] = cache.file_hash(p, rel) if cache is not None else sha256_file(p)
    return result
