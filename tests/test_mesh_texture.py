"""The texture atlas of ``model.glb`` (go_core.mesh.texture): texels map onto their faces, a bake from
synthetic views of a coloured sphere gives back its colours, and the written glTF, read back by trimesh and
ray-cast (go_core.metrics.mesh_render), shows them where the views did."""

from __future__ import annotations

import numpy as np
import pytest

from go_core.mesh.files import read_glb_world, write_glb
from go_core.mesh.surface import marching_cubes
from go_core.mesh.texture import dilate_texture, texel_samples, textured_mesh
from go_core.mesh.tsdf import FusionRule, View
from go_core.mesh.types import TriMesh
from tests._synthetic_depth import _rays, ring_cameras, sphere_cameras_around, sphere_depth

RADIUS = 0.8


def pattern(points: np.ndarray) -> np.ndarray:
    """A smooth colour field on the sphere: bands along z, a ramp along x and y."""
    p = np.asarray(points, np.float64)
    return np.stack(
        [0.5 + 0.4 * np.sin(5.0 * p[:, 2]), 0.5 + 0.4 * p[:, 0] / RADIUS, 0.5 + 0.4 * p[:, 1] / RADIUS], 1
    ).astype(np.float32)


def _views(size: int = 128) -> list[View]:
    ring = ring_cameras(8, size=size)
    views = []
    for cam in ring + sphere_cameras_around(16, ring[0]):
        depth, alpha = sphere_depth(cam, RADIUS)
        o, d = _rays(cam)
        rgb = pattern(o + depth.reshape(-1, 1) * d).reshape(cam.height, cam.width, 3)
        views.append(View(cam, depth.astype(np.float32), alpha, rgb * alpha[..., None]))
    return views


def _sphere(n: int = 40) -> TriMesh:
    x = np.linspace(-1.0, 1.0, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    return marching_cubes(np.sqrt(X**2 + Y**2 + Z**2) - RADIUS, np.full(3, -1.0), x[1] - x[0])


def test_texel_samples_cover_a_square_once_at_their_centres():
    uvs = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    w, h = 8, 4
    idx, face, bary = texel_samples(faces, uvs, (w, h))
    assert np.array_equal(idx, np.arange(w * h))  # every texel once
    uv = np.einsum("nk,nkd->nd", bary, uvs[faces[face]])
    x, y = idx % w, idx // w
    assert np.allclose(uv[:, 0], (x + 0.5) / w) and np.allclose(uv[:, 1], 1.0 - (y + 0.5) / h)  # row 0: v = 1


def test_dilation_fills_the_gutter_from_neighbours_only():
    tex = np.zeros((5, 5, 3), np.float32)
    filled = np.zeros((5, 5), bool)
    tex[2, 2], filled[2, 2] = (0.2, 0.4, 0.6), True
    out = dilate_texture(tex, filled, 1)
    assert np.allclose(out[1:4, 1:4], (0.2, 0.4, 0.6))  # the 8 neighbours take the colour
    assert np.allclose(out[0], 0) and np.allclose(out[:, 4], 0)  # two texels away: untouched


@pytest.fixture(scope="module")
def baked():
    views = _views()
    rule = FusionRule(truncation=0.05, alpha_threshold=0.5, carve_alpha=0.05, occluded_weight=0.0)
    grey = lambda p: np.full((len(p), 3), 0.5, np.float32)  # noqa: E731
    return textured_mesh(_sphere(), views, rule, grey, resolution=256, sharpness=1.0), views


def test_bake_gives_back_the_colours_the_views_saw(baked):
    tex, _ = baked
    h, w = tex.texture.shape[:2]
    idx, face, bary = texel_samples(tex.faces, tex.uvs, (w, h))
    points = np.einsum("nk,nkd->nd", bary, tex.vertices[tex.faces[face]])
    on_sphere = points * (RADIUS / np.linalg.norm(points, axis=1, keepdims=True))
    got = tex.texture.reshape(-1, 3)[idx].astype(np.float64) / 255.0
    err = np.abs(got - pattern(on_sphere))
    assert err.mean() < 0.02, err.mean()  # the pattern spans 0.1-0.9: the bake follows it
    assert np.quantile(err, 0.99) < 0.1


def test_textured_glb_reloads_with_its_counts_and_shows_the_baked_colours(baked, tmp_path):
    pytest.importorskip("embreex", reason="ray casting the mesh needs embreex (pip install embreex)")
    from go_core.metrics.mesh_render import render_mesh

    tex, views = baked
    up, centre = np.array([0, 0, 1.0]), np.array([0.1, -0.2, 0.3])
    mesh = read_glb_world(write_glb(tex, tmp_path / "t.glb", up=up, centre=centre), up, centre)
    assert mesh.visual.kind == "texture"
    assert len(mesh.vertices) == len(tex.vertices) and len(mesh.faces) == len(tex.faces)
    assert np.allclose(mesh.vertices, tex.vertices, atol=1e-5)  # back in the world frame
    for view in views[:3]:
        rgb, cover = render_mesh(mesh, view.camera, supersample=1)
        both = (cover > 0.5) & (view.alpha > 0.5)
        assert both.mean() > 0.2
        assert np.abs(rgb[both] - view.rgb[both]).mean() < 0.03  # a flipped v would scramble the bands


def test_camera_rays_pass_through_their_pixel_centres():
    from go_core.metrics.mesh_render import camera_rays

    cam = ring_cameras(1, size=16)[0]
    origins, dirs = camera_rays(cam, supersample=2)
    uv, z = cam.project(origins + 2.5 * dirs)
    j, i = np.mgrid[0:32, 0:32]
    assert np.allclose(uv[:, 0], ((i + 0.5) / 2).ravel()) and np.allclose(uv[:, 1], ((j + 0.5) / 2).ravel())
    assert (z > 0).all() and np.allclose(np.linalg.norm(dirs, axis=1), 1.0)
