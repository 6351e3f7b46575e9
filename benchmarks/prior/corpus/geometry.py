"""Mesh geometry for the corpus: read an OBJ's triangles, sample its surface, compare two shapes.

Shapes are compared after normalising each axis of the bounding box to [-0.5, 0.5] (``box_normalised``), so
a copy of a mesh that was rescaled, uniformly or per axis, compares as the same shape; the Chamfer distance
is taken as the minimum over the 6 permutations of the axes (a copy stored with another up axis is still the
same shape).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from go_core.errors import GoError
from go_core.seeding import numpy_rng


@dataclass(frozen=True)
class Mesh:
    vertices: np.ndarray  # [N, 3] float64
    faces: np.ndarray  # [F, 3] int64 (triangles)


def read_obj(paths: list[Path] | Path) -> Mesh:
    """The triangles of one or more OBJ files joined into one mesh (polygons fan-triangulated; texture and
    normal indices ignored). One GoError naming the file when it has no vertex or an index is out of range."""
    paths = [paths] if isinstance(paths, Path) else list(paths)
    verts: list[np.ndarray] = []
    faces: list[np.ndarray] = []
    offset = 0
    for path in paths:
        v, f = _read_one(Path(path))
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
    return Mesh(np.concatenate(verts), np.concatenate(faces))


def _read_one(path: Path) -> tuple[np.ndarray, np.ndarray]:
    vs: list[list[float]] = []
    tris: list[tuple[int, int, int]] = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if line.startswith("v "):
                vs.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("f "):
                idx = [int(tok.split("/")[0]) for tok in line.split()[1:]]
                idx = [i - 1 if i > 0 else len(vs) + i for i in idx]  # OBJ: 1-based, negative = relative
                tris.extend((idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1))
    if not vs:
        raise GoError("the OBJ file holds no vertex", path)
    v = np.asarray(vs, np.float64)
    f = np.asarray(tris, np.int64).reshape(-1, 3)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise GoError("a face index of the OBJ file is out of range", path)
    return v, f


def surface_samples(mesh: Mesh, count: int, seed: int) -> np.ndarray:
    """``count`` points drawn uniformly (by area) on the triangles; the vertices when there are no faces."""
    rng = numpy_rng(seed, "surface_samples")
    if len(mesh.faces) == 0:
        return mesh.vertices[rng.choice(len(mesh.vertices), size=count)]
    a, b, c = (mesh.vertices[mesh.faces[:, k]] for k in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    if area.sum() <= 0:
        return mesh.vertices[rng.choice(len(mesh.vertices), size=count)]
    tri = rng.choice(len(area), size=count, p=area / area.sum())
    u, w = rng.random(count), rng.random(count)
    flip = u + w > 1
    u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
    return a[tri] + u[:, None] * (b[tri] - a[tri]) + w[:, None] * (c[tri] - a[tri])


def box_extent(points: np.ndarray) -> np.ndarray:
    """The bounding box's side lengths."""
    return points.max(0) - points.min(0)


def box_normalised(points: np.ndarray) -> np.ndarray:
    """Each axis of the bounding box mapped to [-0.5, 0.5] (a flat axis stays 0)."""
    lo, hi = points.min(0), points.max(0)
    span = np.where(hi - lo > 0, hi - lo, 1.0)
    return (points - 0.5 * (lo + hi)) / span


def chamfer(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric mean nearest-neighbour distance between two point sets."""
    from scipy.spatial import cKDTree

    da, _ = cKDTree(b).query(a)
    db, _ = cKDTree(a).query(b)
    return float(0.5 * (da.mean() + db.mean()))


def shape_distance(a: np.ndarray, b: np.ndarray) -> tuple[float, tuple[int, int, int]]:
    """Chamfer distance of the box-normalised point sets, the minimum over permutations of ``b``'s axes;
    returns (distance, the permutation)."""
    na = box_normalised(a)
    best = (float("inf"), (0, 1, 2))
    for perm in itertools.permutations(range(3)):
        d = chamfer(na, box_normalised(b[:, perm]))
        best = min(best, (d, perm))
    return best


def same_vertices(a: np.ndarray, b: np.ndarray) -> float:
    """Largest offset between vertex i of ``a`` and vertex i of ``b`` once both bounding boxes are
    normalised, the minimum over permutations of ``b``'s axes (inf when the counts differ)."""
    if len(a) != len(b):
        return float("inf")
    na = box_normalised(a)
    return min(
        float(np.abs(na - box_normalised(b[:, perm])).max()) for perm in itertools.permutations(range(3))
    )


def extent_ratio_gap(a: np.ndarray, b: np.ndarray) -> float:
    """How far the sorted bounding-box aspect ratios of two shapes differ (0: same proportions)."""
    ea, eb = np.sort(box_extent(a)), np.sort(box_extent(b))
    ra, rb = ea / max(ea[-1], 1e-12), eb / max(eb[-1], 1e-12)
    return float(np.abs(ra - rb).max())
