"""The mesh data the stage passes around, with no algorithm attached: a coloured triangle mesh
(``TriMesh``) and a textured one (``TexturedMesh``). Kept apart from the algorithms (go_core.mesh.surface,
texture, tsdf) so that modules which only read or write meshes, such as the scene step's check of a
ground-truth mesh, do not carry the algorithms' code in their steps' cache keys (go_pipeline.codehash)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class TriMesh:
    """vertices [V,3] float64 (world), faces [F,3] int64 (counter-clockwise seen from outside), colours
    [V,3] float32 in [0,1] or None."""

    vertices: np.ndarray
    faces: np.ndarray
    colours: np.ndarray | None = None

    def face_normals(self) -> np.ndarray:
        """Unit normals [F,3] (zero for degenerate faces)."""
        tri = self.vertices[self.faces]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, length, out=np.zeros_like(n), where=length > 0)

    def areas(self) -> np.ndarray:
        tri = self.vertices[self.faces]
        return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)

    def volume(self) -> float:
        """Signed enclosed volume (positive for a closed mesh with outward normals)."""
        tri = self.vertices[self.faces]
        return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)


@dataclass
class TexturedMesh:
    """Vertices [V,3] (a vertex per chart corner: xatlas splits seams), faces [F,3], texture coordinates
    ``uvs`` [V,2] in [0, 1] (v up) and the ``texture`` [H,W,3] uint8 (row 0 at the top: v = 1)."""

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    texture: np.ndarray


__all__ = ["TexturedMesh", "TriMesh"]
