"""Keep the reserved objects, and every recoloured or rescaled copy of them, out of the corpus, by geometry.

The reserved objects (the dev scenes and the held-out evaluation objects) are found by name once; their
copies are found by shape, whatever their name: an object is excluded when
* it is a reserved object itself (``reserved``);
* its mesh is a reserved mesh with each bounding-box axis rescaled and the axes perhaps permuted: the same
  vertex count, and vertex i of one within ``SAME_MESH_TOLERANCE`` of vertex i of the other once both
  boxes are normalised (``same mesh``: a recolour or a rescale, uniform or not);
* or it is a different mesh of the same shape: box-normalised Chamfer below ``chamfer_threshold`` and the
  bounding-box proportions within ``RATIO_GAP`` (``similar shape``: a re-meshed copy, or the same bottle
  or can with another label). Box normalisation alone would make every box-shaped package one shape, hence
  the proportions.
Every object's nearest reserved mesh, distance and proportions gap is reported, kept or not, so the
thresholds can be judged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import Mesh, extent_ratio_gap, same_vertices, shape_distance, surface_samples

RESERVED = (
    "alphabet_soup",
    "basket",
    "milk",
    "plate",
    "white_bowl",
    "akita_black_bowl",
    "chefmate_8_frypan",
    "glazed_rim_porcelain_ramekin",
    "ketchup",
    "macaroni_and_cheese",
    "orange_juice",
)
CHAMFER_THRESHOLD = 0.03  # box-normalised units (each box side is 1)
RATIO_GAP = 0.05  # sorted bounding-box sides over the longest: largest difference
SAME_MESH_TOLERANCE = 1e-3  # box-normalised units, largest vertex offset
SAMPLES = 2000


@dataclass(frozen=True)
class Shape:
    """What the exclusion compares: the vertices (in file order) and area-uniform surface samples."""

    name: str
    vertices: np.ndarray
    points: np.ndarray

    @property
    def vertex_count(self) -> int:
        return len(self.vertices)

    @staticmethod
    def of(name: str, mesh: Mesh, seed: int = 0) -> Shape:
        return Shape(name, mesh.vertices, surface_samples(mesh, SAMPLES, seed))


def same_mesh(a: Shape, b: Shape) -> bool:
    """``a`` is ``b``'s mesh rescaled per axis (and its axes perhaps permuted)."""
    return a.vertex_count == b.vertex_count and same_vertices(a.vertices, b.vertices) < SAME_MESH_TOLERANCE


def judge(shape: Shape, reserved: list[Shape], chamfer_threshold: float = CHAMFER_THRESHOLD) -> dict:
    """The verdict on one object: {"excluded": bool, "reason": str, "nearest": name, "chamfer": d,
    "ratio_gap": g}. ``reserved``: the reserved objects' shapes (a name listed there is itself reserved)."""
    if not reserved:
        raise ValueError("no reserved shape to compare with: the exclusion cannot be checked")
    rows = []
    for ref in reserved:
        d, perm = shape_distance(shape.points, ref.points)
        gap = extent_ratio_gap(shape.points, ref.points)
        rows.append((d, gap, perm, ref))
    d, gap, perm, ref = min(rows, key=lambda r: r[0])
    verdict = {"nearest": ref.name, "chamfer": round(d, 5), "ratio_gap": round(gap, 4), "axes": list(perm)}
    if shape.name in {r.name for r in reserved}:
        return {**verdict, "excluded": True, "reason": "reserved object"}
    same = [r for r in rows if same_mesh(shape, r[3])]
    if same:
        other = same[0][3]
        why = f"same mesh as reserved {other.name} ({shape.vertex_count} vertices), rescaled or recoloured"
        return {**verdict, "excluded": True, "reason": why}
    similar = [r for r in rows if r[0] < chamfer_threshold and r[1] < RATIO_GAP]
    if similar:
        d1, g1, _, other = min(similar, key=lambda r: r[0])
        why = (
            f"similar shape to reserved {other.name}: box-normalised Chamfer {d1:.4f} < {chamfer_threshold}, "
            f"proportions within {g1:.3f} < {RATIO_GAP}"
        )
        return {**verdict, "excluded": True, "reason": why}
    return {**verdict, "excluded": False, "reason": ""}
