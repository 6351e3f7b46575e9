"""Deterministic ``.npz`` files: equal arrays give equal bytes (cache keys and rerun checks rely on it)."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np

from go_core.io.atomic import atomic_write

_ZIP_DATE = (1980, 1, 1, 0, 0, 0)  # fixed timestamp: equal content gives equal bytes


def write_npz_deterministic(path: str | Path, arrays: dict[str, np.ndarray]) -> Path:
    """Write an ``.npz`` (readable by ``np.load``) whose bytes depend only on the arrays: sorted names,
    fixed zip timestamps, deflate compression. ``np.savez`` stamps the current time into the zip."""

    def write(tmp: Path) -> None:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=6) as zf:
            for name in sorted(arrays):
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.ascontiguousarray(arrays[name]), allow_pickle=False)
                info = zipfile.ZipInfo(name + ".npy", date_time=_ZIP_DATE)
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                zf.writestr(info, buf.getvalue(), compresslevel=6)

    return atomic_write(path, write)
