"""A picture of a mesh for the report: flat Lambert shading (or vertex colours), triangles painted far to
near with OpenCV (a painter's algorithm: exact for the convex parts that dominate object meshes, and
independent of the Gaussian rasterizer)."""

from __future__ import annotations

import numpy as np

from go_core.mesh.types import TriMesh


def shaded(mesh: TriMesh, camera, use_colours: bool = False, background: int = 255) -> np.ndarray:
    """uint8 [H,W,3] image of ``mesh`` seen by ``camera``: grey shaded by the angle to the view direction
    (a headlight), or the mean vertex colour of each face times that shading."""
    import cv2

    uv, z = camera.project(mesh.vertices)
    img = np.full((camera.height, camera.width, 3), background, np.uint8)
    faces = mesh.faces[(z[mesh.faces] > 1e-6).all(1)]
    if len(faces) == 0:
        return img
    centres = mesh.vertices[faces].mean(1)
    normals = TriMesh(mesh.vertices, faces).face_normals()
    to_cam = camera.center - centres
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
    light = 0.25 + 0.75 * np.abs(np.einsum("ij,ij->i", normals, to_cam))
    if use_colours and mesh.colours is not None:
        base = mesh.colours[faces].mean(1) * 255.0
    else:
        base = np.full((len(faces), 3), 200.0)
    colour = np.clip(base * light[:, None], 0, 255).astype(np.uint8)
    order = np.argsort(-z[faces].mean(1), kind="stable")
    fixed = np.round((uv - 0.5) * 16).astype(np.int64)[faces]
    ok = (np.abs(fixed) < (1 << 20)).all(axis=(1, 2))
    for i in order[ok[order]]:
        cv2.fillConvexPoly(img, fixed[i].astype(np.int32), colour[i].tolist(), lineType=cv2.LINE_AA, shift=4)
    return img
