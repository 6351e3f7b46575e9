"""Pictures of an exported mesh, made independently of the Gaussian renderer: one ray per sub-pixel cast
through the mesh (Embree, through trimesh's ``RayMeshIntersector``), the first hit's colour from the mesh's
own visual as a viewer reads it: vertex colours interpolated across the face, or the base-colour texture
sampled bilinearly at the interpolated texture coordinates (``trimesh.visual.uv_to_interpolated_color``).
Used to measure what a textured ``model.glb`` shows against the vertex-coloured one (docs/geometry.md)."""

from __future__ import annotations

import numpy as np


def camera_rays(camera, supersample: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """World ray origins and unit directions [H·W·s², 3] through the sub-pixel centres of ``camera``, in
    row-major order of the ``supersample`` times finer image (pixel column i spans u ∈ [i, i + 1))."""
    k = int(supersample)
    h, w = camera.height * k, camera.width * k
    u, v = np.meshgrid((np.arange(w) + 0.5) / k, (np.arange(h) + 0.5) / k)
    K = np.asarray(camera.K, np.float64)
    y = (v - K[1, 2]) / K[1, 1]
    x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
    d_cam = np.stack([x, y, np.ones_like(x)], axis=-1).reshape(-1, 3)
    R = np.asarray(camera.world_to_cam, np.float64)[:3, :3]
    d = d_cam @ R  # R^T applied to each row
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.broadcast_to(camera.center, d.shape).copy(), d


def _colours_at(mesh, tri: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """RGB [N,3] in [0,1] of ``mesh``'s visual at barycentric ``bary`` on faces ``tri``."""
    from trimesh.visual import uv_to_interpolated_color

    corners = mesh.faces[tri]
    visual = mesh.visual
    if visual.kind == "texture":
        uv = np.einsum("nk,nkd->nd", bary, np.asarray(visual.uv, np.float64)[corners])
        image = visual.material.baseColorTexture if hasattr(visual.material, "baseColorTexture") else None
        image = image if image is not None else visual.material.image
        rgba = uv_to_interpolated_color(uv, image)
        return np.asarray(rgba, np.float64)[:, :3] / 255.0
    if visual.kind == "vertex":
        vc = np.asarray(visual.vertex_colors, np.float64)[:, :3] / 255.0
        return np.einsum("nk,nkd->nd", bary, vc[corners])
    raise ValueError(f"the mesh has no vertex colours nor a texture (visual kind {visual.kind!r})")


def render_mesh(mesh, camera, supersample: int = 2, background: float = 1.0):
    """(rgb [H,W,3] float32 over ``background``, coverage [H,W] float32 in [0,1]) of the trimesh ``mesh``
    seen by ``camera``, ``supersample``² rays per pixel averaged."""
    from trimesh.ray.ray_pyembree import RayMeshIntersector
    from trimesh.triangles import points_to_barycentric

    origins, dirs = camera_rays(camera, supersample)
    locations, ray, tri = RayMeshIntersector(mesh).intersects_location(origins, dirs, multiple_hits=False)
    rgb = np.full((len(dirs), 3), float(background))
    hit = np.zeros(len(dirs))
    if len(ray):
        bary = points_to_barycentric(mesh.triangles[tri], locations)
        rgb[ray] = np.clip(_colours_at(mesh, tri, np.clip(bary, 0.0, 1.0)), 0.0, 1.0)
        hit[ray] = 1.0
    k = int(supersample)
    h, w = camera.height, camera.width
    rgb = rgb.reshape(h, k, w, k, 3).mean(axis=(1, 3))
    cover = hit.reshape(h, k, w, k).mean(axis=(1, 3))
    return rgb.astype(np.float32), cover.astype(np.float32)


__all__ = ["camera_rays", "render_mesh"]
