"""INRIA 3DGS ``.ply`` layout (what SuperSplat, the SIBR viewer and most web viewers read).

One binary little-endian vertex element with float32 properties, in this order:
``x y z nx ny nz f_dc_0..2 f_rest_0..44 opacity scale_0..2 rot_0..3``.
* ``f_rest`` is channel-major: ``f_rest_{c·15 + j} = sh[:, 1 + j, c]``; sets with SH degree < 3 are
  zero-padded per channel to degree 3 (45 values) for viewer compatibility;
* ``opacity`` is the logit, ``scale_*`` are natural logs, ``rot_*`` is the w-first quaternion (as stored);
* normals are zeros (3DGS writes them so).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from go_core.errors import GoError
from go_core.gaussians import Gaussians, sh_degree_of
from go_core.io.atomic import atomic_write
from go_core.sh import num_sh_bases

PLY_SH_DEGREE = 3
_TYPES = {
    "float": "<f4",
    "float32": "<f4",
    "double": "<f8",
    "float64": "<f8",
    "uchar": "u1",
    "uint8": "u1",
    "int": "<i4",
    "int32": "<i4",
    "uint": "<u4",
    "uint32": "<u4",
    "short": "<i2",
    "ushort": "<u2",
}


def ply_property_names(degree: int = PLY_SH_DEGREE) -> list[str]:
    n_rest = 3 * (num_sh_bases(degree) - 1)
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(n_rest)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )


def gaussians_to_ply_array(g: Gaussians, degree: int = PLY_SH_DEGREE) -> np.ndarray:
    """[N, 62] float32 rows in the INRIA property order (SH padded or truncated to ``degree``)."""
    g = g.detach().to(dtype=torch.float32).with_sh_degree(degree)
    n = len(g)
    sh = g.sh.cpu().numpy()  # [N,K,3]
    rest = sh[:, 1:, :].transpose(0, 2, 1).reshape(n, -1)  # channel-major
    cols = [
        g.means.cpu().numpy(),
        np.zeros((n, 3), np.float32),
        sh[:, 0, :],
        rest,
        g.opacity_logits.cpu().numpy().reshape(n, 1),
        g.log_scales.cpu().numpy(),
        g.quats.cpu().numpy(),
    ]
    return np.concatenate(cols, axis=1).astype(np.float32)


def save_ply(g: Gaussians, path: str | Path, degree: int = PLY_SH_DEGREE) -> Path:
    """Write ``g`` as an INRIA-layout binary .ply atomically."""
    rows = gaussians_to_ply_array(g, degree)
    names = ply_property_names(degree)
    header = "ply\nformat binary_little_endian 1.0\n"
    header += f"element vertex {rows.shape[0]}\n"
    header += "".join(f"property float {name}\n" for name in names)
    header += "end_header\n"

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            f.write(header.encode("ascii"))
            f.write(np.ascontiguousarray(rows, dtype="<f4").tobytes())

    return atomic_write(path, write)


def _read_header(f, path: Path) -> tuple[int, list[tuple[str, str]], str]:
    if f.readline().strip() != b"ply":
        raise GoError("not a .ply file (missing 'ply' magic)", path=path)
    fmt, count, props, in_vertex = None, None, [], False
    while True:
        line = f.readline()
        if not line:
            raise GoError("truncated .ply header (no end_header)", path=path)
        parts = line.decode("ascii", errors="replace").split()
        if not parts or parts[0] in ("comment", "obj_info"):
            continue
        if parts[0] == "end_header":
            break
        if parts[0] == "format":
            fmt = parts[1]
        elif parts[0] == "element":
            in_vertex = parts[1] == "vertex"
            if in_vertex:
                count = int(parts[2])
            elif count is not None:
                raise GoError(f"unsupported .ply: element {parts[1]!r} after the vertices", path=path)
        elif parts[0] == "property" and in_vertex:
            if parts[1] == "list" or parts[1] not in _TYPES:
                raise GoError(f"unsupported .ply vertex property type {parts[1]!r}", path=path)
            props.append((parts[2], _TYPES[parts[1]]))
    if fmt != "binary_little_endian" or count is None:
        raise GoError(f"unsupported .ply (format {fmt!r}; need binary_little_endian vertices)", path=path)
    return count, props, fmt


def load_ply(path: str | Path, sh_degree: int | None = None) -> Gaussians:
    """Read an INRIA-layout .ply; ``sh_degree`` truncates/pads the SH (default: what the file holds)."""
    path = Path(path)
    with open(path, "rb") as f:
        count, props, _ = _read_header(f, path)
        dtype = np.dtype([(name, t) for name, t in props])
        data = np.frombuffer(f.read(count * dtype.itemsize), dtype=dtype, count=count)
    names = set(dtype.names or ())
    required = [
        "x",
        "y",
        "z",
        "f_dc_0",
        "f_dc_1",
        "f_dc_2",
        "opacity",
        "scale_0",
        "scale_1",
        "scale_2",
        "rot_0",
        "rot_1",
        "rot_2",
        "rot_3",
    ]
    missing = [n for n in required if n not in names]
    if missing:
        raise GoError(f"not a 3DGS .ply: missing properties {missing}", path=path)

    def col(*ns: str) -> np.ndarray:
        return np.stack([np.asarray(data[n], np.float32) for n in ns], axis=1)

    n_rest = len([n for n in names if n.startswith("f_rest_")])
    file_degree = sh_degree_of(n_rest // 3 + 1)
    sh = np.zeros((count, num_sh_bases(file_degree), 3), np.float32)
    sh[:, 0, :] = col("f_dc_0", "f_dc_1", "f_dc_2")
    if n_rest:
        rest = col(*[f"f_rest_{i}" for i in range(n_rest)]).reshape(count, 3, -1)
        sh[:, 1:, :] = rest.transpose(0, 2, 1)
    g = Gaussians(
        torch.from_numpy(col("x", "y", "z")),
        torch.from_numpy(col("rot_0", "rot_1", "rot_2", "rot_3")),
        torch.from_numpy(col("scale_0", "scale_1", "scale_2")),
        torch.from_numpy(np.asarray(data["opacity"], np.float32).copy()),
        torch.from_numpy(sh),
    )
    return g.with_sh_degree(file_degree if sh_degree is None else sh_degree)
