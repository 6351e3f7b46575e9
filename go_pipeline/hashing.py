"""Content hashes and cache keys.

* ``canonical_json``: the one JSON spelling hashed into keys (sorted keys, no spaces, exact floats).
* ``cache_key``: sha256 of the step name, its code (go_pipeline.codehash), an optional VERSION override,
  resolved params, seed and its inputs' content hashes.
* ``files_hash``: content hash of a set of files (relative name + bytes), used for artifacts and the scene.
* ``FileHashCache``: per-file sha256 remembered by the file's absolute real path and (device, inode, size,
  mtime_ns, ctime_ns), so a no-op run over an unchanged scene folder only stats its files, and a copy of a
  scene (same names, sizes and timestamps, other bytes) never reuses another file's hash.
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
    function: str = "",
    external: dict[str, Any] | None = None,
) -> str:
    """``inputs`` maps input name -> content hash of that input (an artifact or the scene folder);
    ``code`` is the digest of the source files the step runs; ``version`` the module's optional VERSION
    override (None when it defines none); ``function`` is the step's ``module:callable`` (another function
    is another computation); ``external``: what it reads from outside the work dir (go_pipeline.external:
    library versions, model files, LPIPS weights)."""
    material = {
        "step": step,
        "version": version,
        "code": code,
        "function": function,
        "external": external or {},
        "params": params,
        "seed": int(seed),
        "inputs": inputs,
    }
    return hashlib.sha256(canonical_json(material).encode("utf-8")).hexdigest()


def walk_files(root: Path, exclude: Iterable[Path] = ()) -> list[Path]:
    """Every regular file under ``root``, following symlinked files and folders (a symlinked ``train/``
    holds images the reader opens), each real folder once; skipping the ``exclude`` dirs. Paths are as
    seen from ``root`` (not resolved)."""
    excluded = {os.path.realpath(p) for p in exclude}
    found: list[Path] = []
    seen_dirs: set[str] = set()
    for dirpath, dirnames, filenames in os.walk(root, followlinks=True):
        real = os.path.realpath(dirpath)
        if real in seen_dirs:  # a symlink cycle, or a folder reached twice
            dirnames[:] = []
            continue
        seen_dirs.add(real)
        dirnames[:] = sorted(
            d for d in dirnames if os.path.realpath(os.path.join(dirpath, d)) not in excluded
        )
        for name in sorted(filenames):
            p = Path(dirpath) / name
            if p.is_file():
                found.append(p)
    return found


class FileHashCache:
    """sha256 of files keyed by absolute real path, checked against (device, inode, size, mtime_ns,
    ctime_ns); saved as JSON (atomically) on ``save``. ``ctime_ns`` cannot be set from user space, so a
    file rewritten with its old size and mtime restored (``touch -r``, ``cp -p``) is hashed again."""

    VERSION = 2

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self._entries: dict[str, list] = {}
        self._dirty = False
        if path is not None and path.is_file():
            try:
                data = json.loads(path.read_text(encoding="utf-8"))
                if isinstance(data, dict) and data.get("version") == self.VERSION:
                    self._entries = dict(data.get("files") or {})
            except (OSError, ValueError):
                self._entries = {}  # a corrupt cache is only a cache

    def file_hash(self, path: Path, rel: str | None = None) -> str:
        """sha256 of ``path``'s bytes (following symlinks); ``rel`` is accepted for compatibility."""
        real = os.path.realpath(path)
        st = os.stat(real)
        stamp = [st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns]
        hit = self._entries.get(real)
        if isinstance(hit, list) and len(hit) == 6 and hit[:5] == stamp:
            return hit[5]
        digest = sha256_file(real)
        self._entries[real] = [*stamp, digest]
        self._dirty = True
        return digest

    def save(self) -> None:
        if self.path is None or not self._dirty:
            return
        from go_core.io.atomic import atomic_write_text

        data = {"version": self.VERSION, "files": self._entries}
        atomic_write_text(self.path, json.dumps(data, sort_keys=True))
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
