"""Mesh files: ``model_mesh.ply`` (binary PLY, world frame, vertex colours), ``model.glb`` (glTF 2.0 binary,
+Y up as glTF requires, vertex colours as COLOR_0 or a baked texture) through trimesh, and the ground-truth
``mesh_world.npz`` (``vertices`` [V,3], ``faces`` [F,3], the scene's world frame) of the dev scenes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from go_core.mesh.types import TexturedMesh, TriMesh


def _trimesh(mesh: TriMesh, vertices: np.ndarray | None = None):
    import trimesh

    colours = None
    if mesh.colours is not None:
        rgb = np.round(np.clip(mesh.colours, 0, 1) * 255).astype(np.uint8)
        colours = np.concatenate([rgb, np.full((len(rgb), 1), 255, np.uint8)], axis=1)
    verts = mesh.vertices if vertices is None else vertices
    return trimesh.Trimesh(verts, mesh.faces, vertex_colors=colours, process=False)


def up_to_y(up: np.ndarray) -> np.ndarray:
    """A rotation [3,3] taking the unit vector ``up`` onto +Y (Rodrigues; a half turn about X if opposite)."""
    a = np.asarray(up, np.float64) / np.linalg.norm(up)
    b = np.array([0.0, 1.0, 0.0])
    v, c = np.cross(a, b), float(a @ b)
    if c < -1.0 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def write_ply(mesh: TriMesh, path: str | Path) -> Path:
    """Binary little-endian PLY with per-vertex RGBA (when coloured), world frame, written atomically."""
    from go_core.io.atomic import atomic_write_bytes

    data = _trimesh(mesh).export(file_type="ply", encoding="binary")
    return atomic_write_bytes(path, data)


def _textured_trimesh(mesh: TexturedMesh, vertices: np.ndarray):
    import trimesh
    from PIL import Image

    visual = trimesh.visual.TextureVisuals(uv=mesh.uvs, image=Image.fromarray(mesh.texture))
    return trimesh.Trimesh(vertices, mesh.faces, visual=visual, process=False)


def write_glb(mesh: TriMesh | TexturedMesh, path: str | Path, up: np.ndarray, centre: np.ndarray) -> Path:
    """glTF 2.0 binary: vertices moved so ``centre`` is the origin and turned so ``up`` is +Y; vertex
    colours (COLOR_0) for a ``TriMesh``, a base-colour texture (PNG) for a ``TexturedMesh``."""
    from go_core.io.atomic import atomic_write_bytes

    verts = (mesh.vertices - np.asarray(centre, np.float64)) @ up_to_y(up).T
    tm = _textured_trimesh(mesh, verts) if isinstance(mesh, TexturedMesh) else _trimesh(mesh, verts)
    return atomic_write_bytes(path, tm.export(file_type="glb"))


def read_glb_world(path: str | Path, up: np.ndarray, centre: np.ndarray):
    """A ``write_glb`` file as a trimesh mesh back in the world frame (its visual as stored)."""
    import trimesh

    m = trimesh.load(Path(path), file_type="glb", process=False, force="mesh")
    m.vertices = np.asarray(m.vertices, np.float64) @ up_to_y(up) + np.asarray(centre, np.float64)
    return m


def read_mesh_npz(path: str | Path) -> TriMesh:
    """A ``vertices`` + ``faces`` npz (the dev scenes' ground truth); one-line errors for a bad file."""
    from go_core.errors import SceneError

    try:
        with np.load(path) as data:
            verts, faces = np.asarray(data["vertices"], np.float64), np.asarray(data["faces"], np.int64)
    except (OSError, KeyError, ValueError) as exc:
        raise SceneError(f"cannot read a mesh with 'vertices' and 'faces': {exc}", Path(path)) from exc
    if verts.ndim != 2 or verts.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise SceneError("mesh arrays must be vertices [V,3] and faces [F,3]", Path(path))
    if len(faces) == 0 or faces.min() < 0 or faces.max() >= len(verts) or not np.isfinite(verts).all():
        raise SceneError("mesh faces index missing vertices (or vertices are not finite)", Path(path))
    return TriMesh(verts, faces)


def read_ply(path: str | Path) -> TriMesh:
    """A mesh written by ``write_ply`` (colours kept when present)."""
    import trimesh

    m = trimesh.load(Path(path), file_type="ply", process=False, force="mesh")
    colours = None
    vc = getattr(m.visual, "vertex_colors", None)
    if vc is not None and len(vc) == len(m.vertices):
        colours = np.asarray(vc, np.float32)[:, :3] / 255.0
    return TriMesh(np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64), colours)
