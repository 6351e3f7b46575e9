"""Triangle meshes from fields: marching cubes (scikit-image), the largest connected component, decimation
to a face budget (fast-simplification) and vertex colours sampled from a colour volume."""

from __future__ import annotations

import numpy as np

from go_core.mesh.types import TriMesh


def marching_cubes(field: np.ndarray, origin: np.ndarray, voxel: float, level: float = 0.0) -> TriMesh:
    """The ``level`` set of ``field`` (positive outside, negative inside) on the grid whose voxel (0,0,0)
    is at ``origin``; the field is padded with an outside border so the surface is closed."""
    from skimage.measure import marching_cubes as skimage_mc

    inside = -np.pad(np.asarray(field, np.float32), 1, constant_values=max(1.0, level + 1.0)) + level
    if not (inside.max() > 0 > inside.min()):
        raise ValueError("the field has no surface at this level (everything is inside or outside)")
    verts, faces, _, _ = skimage_mc(inside, level=0.0, spacing=(voxel, voxel, voxel))
    verts = verts.astype(np.float64) + np.asarray(origin, np.float64) - voxel
    mesh = TriMesh(verts, faces.astype(np.int64))
    if mesh.volume() < 0:  # outward normals whatever scikit-image's winding convention
        mesh.faces = mesh.faces[:, ::-1].copy()
    return mesh


def largest_component(mesh: TriMesh) -> TriMesh:
    """The connected component (through shared vertices) with the most faces; unused vertices dropped."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n, f = len(mesh.vertices), mesh.faces
    if len(f) == 0:
        return mesh
    rows = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    cols = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    graph = coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    face_label = labels[f[:, 0]]
    biggest = np.bincount(face_label).argmax()
    return compact(mesh, face_label == biggest)


def compact(mesh: TriMesh, keep_faces: np.ndarray) -> TriMesh:
    """The faces ``keep_faces`` selects, with only the vertices they use (order kept)."""
    faces = mesh.faces[keep_faces]
    used = np.unique(faces)
    remap = np.full(len(mesh.vertices), -1, np.int64)
    remap[used] = np.arange(len(used))
    colours = None if mesh.colours is None else mesh.colours[used]
    return TriMesh(mesh.vertices[used], remap[faces], colours)


def decimate(mesh: TriMesh, max_faces: int) -> TriMesh:
    """Quadric decimation (fast-simplification) to at most about ``max_faces`` faces (0: unchanged).
    Colours are dropped: sample them again on the new vertices."""
    if max_faces <= 0 or len(mesh.faces) <= max_faces:
        return mesh
    import fast_simplification

    verts, faces = fast_simplification.simplify(
        mesh.vertices.astype(np.float64), mesh.faces.astype(np.int32), target_count=int(max_faces)
    )
    return largest_component(TriMesh(np.asarray(verts, np.float64), np.asarray(faces, np.int64)))


def sample_colours(
    points: np.ndarray, sums: np.ndarray, counts: np.ndarray, origin: np.ndarray, voxel: float
) -> np.ndarray:
    """Colours [N,3] at world ``points``: trilinear interpolation of the colour sums divided by that of
    their counts (grey where no voxel nearby holds a colour)."""
    from scipy.ndimage import map_coordinates

    coords = ((np.asarray(points, np.float64) - origin) / voxel).T
    count = map_coordinates(counts.astype(np.float32), coords, order=1, mode="nearest")
    rgb = np.stack(
        [map_coordinates(sums[..., c].astype(np.float32), coords, order=1, mode="nearest") for c in range(3)],
        1,
    )
    out = np.full((len(points), 3), 0.5, np.float32)
    ok = count > 1e-6
    out[ok] = np.clip(rgb[ok] / count[ok, None], 0.0, 1.0)
    return out
