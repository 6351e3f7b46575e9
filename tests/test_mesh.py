"""Mesh extraction: TSDF fusion + marching cubes recover analytic shapes from synthetic depth maps; the
largest component, decimation, the hull mesh and the mesh files (PLY, glTF reloaded by trimesh and, where
node has it, checked by the Khronos validator)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from go_core.errors import CollapsedModelError
from go_core.mesh.extract import clip_to_hull, drop_unseen, seen_counts, seen_vertices
from go_core.mesh.files import read_ply, write_glb, write_ply
from go_core.mesh.hull_mesh import hull_mesh
from go_core.mesh.surface import decimate, largest_component, marching_cubes
from go_core.mesh.tsdf import FusionRule, View, VoxelGrid, fuse_narrow_band, fuse_views
from go_core.mesh.types import TriMesh
from go_core.metrics.geometry import geometry_metrics
from tests._synthetic_depth import box_mesh, cube_depth, ring_cameras, sphere_cameras_around, sphere_depth

RADIUS, HALF = 0.8, 0.6


def _cameras():
    ring = ring_cameras(8, size=96)
    return ring + sphere_cameras_around(16, ring[0])


def _fused(depth_fn, band: bool = True, resolution: int = 64):
    cams = _cameras()
    views = [View(c, *depth_fn(c)) for c in cams]
    grid = VoxelGrid.around(np.full(3, -1.0), np.full(3, 1.0), resolution)
    fuse = fuse_narrow_band if band else fuse_views
    tsdf = fuse(grid, views, FusionRule(3.0 * grid.voxel, 0.5, 0.5, 0.0))  # alpha >= 0.5: surface
    return largest_component(marching_cubes(tsdf.field, grid.origin, grid.voxel)), grid.voxel


def test_tsdf_recovers_a_sphere():
    """Radius 0.8 seen by 24 cameras at 96 px, 64^3 voxels (0.037): every vertex within 0.5 voxel of the
    sphere (2.2% of the radius; the depth maps' pixels are 0.024 wide there), volume within 2%."""
    mesh, voxel = _fused(lambda c: sphere_depth(c, RADIUS))
    r = np.linalg.norm(mesh.vertices, axis=1)
    assert np.abs(r - RADIUS).max() < 0.5 * voxel
    assert abs(mesh.volume() / (4 / 3 * np.pi * RADIUS**3) - 1) < 0.02
    c = mesh.vertices[mesh.faces].mean(1)  # outward normals
    assert (np.einsum("ij,ij->i", mesh.face_normals(), c) > 0).mean() > 0.999


def test_seen_vertices_keep_the_outer_surface_and_drop_a_wall_inside():
    """Points on the sphere the views see are seen by some view; points on a sphere of half its radius
    inside it (a wall inside a porous model) and points behind the surface by more than the truncation
    are seen by none."""
    cams = _cameras()
    views = [View(c, *sphere_depth(c, RADIUS)) for c in cams]
    rule = FusionRule(0.05, 0.5, 0.05, 0.0)
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(2000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    outer = seen_vertices(RADIUS * dirs, views, rule)
    assert outer.mean() > 0.999
    assert not seen_vertices(0.5 * RADIUS * dirs, views, rule).any()
    assert not seen_vertices((RADIUS - 0.08) * dirs, views, rule).any()  # 0.08 > the truncation 0.05
    assert not seen_vertices(np.array([[0.0, 0.0, 50.0]]), views, rule).any()  # behind every camera


def test_drop_unseen_keeps_the_seen_shell_and_refuses_a_mesh_nobody_sees():
    """A hollow ball (radii 0.4 and 0.8) meshes as two spheres; the views see the outer one only, so the
    inner wall goes and the outer sphere stays whole. With every view empty nothing is seen and the mesh
    is refused (a see-through model), not returned empty."""
    cams = _cameras()
    views = [View(c, *sphere_depth(c, RADIUS)) for c in cams]
    grid = VoxelGrid.around(np.full(3, -1.0), np.full(3, 1.0), 48)
    rule = FusionRule(3.0 * grid.voxel, 0.5, 0.05, 0.0)
    axes = [grid.origin[i] + grid.voxel * np.arange(grid.shape[i]) for i in range(3)]
    r = np.linalg.norm(np.stack(np.meshgrid(*axes, indexing="ij")), axis=0)
    hollow = marching_cubes(np.maximum(r - RADIUS, 0.5 * RADIUS - r), grid.origin, grid.voxel)
    radii = np.linalg.norm(hollow.vertices, axis=1)
    assert radii.min() < 0.6 * RADIUS and radii.max() > 0.9 * RADIUS  # both walls are there
    kept = drop_unseen(hollow, views, rule)
    assert np.linalg.norm(kept.vertices, axis=1).min() > 0.9 * RADIUS  # the inner wall is gone
    assert len(kept.faces) == np.count_nonzero(radii[hollow.faces].min(axis=1) > 0.75 * RADIUS)
    empty = [View(c, np.full((c.height, c.width), np.nan), np.zeros((c.height, c.width))) for c in cams]
    with pytest.raises(CollapsedModelError, match="see-through"):
        drop_unseen(hollow, empty, rule)


def test_a_wall_one_view_sees_down_a_tunnel_goes_at_two_views():
    """The hollow ball of the test above, but the first view looks down a tunnel onto the inner wall (its
    depth is the inner sphere's): that wall is seen by exactly one view, so ``min_views=1`` counts part of
    it as seen and ``min_views=2`` (the mesh step's default) none of it, while every outer vertex is seen
    by at least two views and the outer sphere stays whole."""
    cams = _cameras()
    inner = 0.5 * RADIUS
    views = [View(cams[0], *sphere_depth(cams[0], inner))]
    views += [View(c, *sphere_depth(c, RADIUS)) for c in cams[1:]]
    grid = VoxelGrid.around(np.full(3, -1.0), np.full(3, 1.0), 48)
    rule = FusionRule(3.0 * grid.voxel, 0.5, 0.05, 0.0)
    axes = [grid.origin[i] + grid.voxel * np.arange(grid.shape[i]) for i in range(3)]
    r = np.linalg.norm(np.stack(np.meshgrid(*axes, indexing="ij")), axis=0)
    hollow = marching_cubes(np.maximum(r - RADIUS, inner - r), grid.origin, grid.voxel)
    radii = np.linalg.norm(hollow.vertices, axis=1)
    counts = seen_counts(hollow.vertices, views, rule)
    assert counts[radii < 0.6 * RADIUS].max() == 1 and counts[radii > 0.9 * RADIUS].min() >= 2
    inside = radii < 0.6 * RADIUS
    seen_once = seen_vertices(hollow.vertices, views, rule, min_views=1)
    assert seen_once[inside].mean() > 0.3  # seen down the tunnel
    assert not seen_vertices(hollow.vertices, views, rule, min_views=2)[inside].any()
    two = drop_unseen(hollow, views, rule, min_views=2)
    assert np.linalg.norm(two.vertices, axis=1).min() > 0.9 * RADIUS
    assert len(two.faces) == np.count_nonzero(radii[hollow.faces].min(axis=1) > 0.75 * RADIUS)


def test_tsdf_recovers_a_cube():
    """The cube [-0.6, 0.6]^3: Chamfer-L1 below half a voxel, F@2% above 0.95 (only the edges and corners
    round off), volume within 3%."""
    mesh, voxel = _fused(lambda c: cube_depth(c, HALF))
    res = geometry_metrics(mesh, box_mesh(HALF), count=50_000, seed=0)
    assert res["chamfer_l1"] < 0.5 * voxel
    assert res["fscore_2pct"] > 0.95 and res["normal_consistency"] > 0.95
    assert abs(mesh.volume() / (2 * HALF) ** 3 - 1) < 0.03


def _see_through_sphere_views(rule: FusionRule, resolution: int = 64):
    """Exact sphere depth from 24 cameras, but every other view sees the sphere as translucent (alpha 0.3
    on it, as a sparse-view Gaussian model renders from unseen directions)."""
    views = []
    for k, c in enumerate(_cameras()):
        depth, alpha = sphere_depth(c, RADIUS)
        views.append(View(c, depth, alpha * (0.3 if k % 2 else 1.0)))
    grid = VoxelGrid.around(np.full(3, -1.0), np.full(3, 1.0), resolution)
    tsdf = fuse_narrow_band(grid, views, FusionRule(3.0 * grid.voxel, 0.5, rule.carve_alpha, 0.0))
    return largest_component(marching_cubes(tsdf.field, grid.origin, grid.voxel)), grid.voxel


def test_translucent_pixels_carve_nothing():
    """Carving only where alpha ≤ 0.05 recovers the sphere from the 12 opaque views (every vertex within
    a voxel, mean within a quarter); carving wherever alpha < 0.5 (the old rule) erases it."""
    kept, voxel = _see_through_sphere_views(FusionRule(1.0, 0.5, 0.05, 0.0))
    err = np.abs(np.linalg.norm(kept.vertices, axis=1) - RADIUS)
    assert err.max() < voxel and err.mean() < 0.25 * voxel
    try:
        carved = _see_through_sphere_views(FusionRule(1.0, 0.5, 0.5, 0.0))[0].volume()
    except ValueError as exc:  # nothing left at all
        assert "no surface" in str(exc)
        carved = 0.0
    assert carved < 0.1 * 4 / 3 * np.pi * RADIUS**3


def test_a_see_through_shell_keeps_its_interior_with_the_free_depth():
    """Every other view sees through a translucent front: its (median) depth is the sphere's back surface,
    its free depth (opacity reaches carve_alpha) the front. With the free depth the sphere is recovered
    (every vertex within a voxel, mean within a quarter); deciding by the pixel alone carves the interior
    away."""
    cams, grid = _cameras(), VoxelGrid.around(np.full(3, -1.0), np.full(3, 1.0), 64)
    rule = FusionRule(3.0 * grid.voxel, 0.5, 0.05, 0.0)
    with_free, without = [], []
    for k, c in enumerate(cams):
        front, alpha = sphere_depth(c, RADIUS)
        free = np.where(alpha > 0, front, np.nan)
        depth = np.where(alpha > 0, sphere_depth(c, RADIUS, back=True)[0] if k % 2 else front, np.nan)
        with_free.append(View(c, depth, alpha, None, free))
        without.append(View(c, depth, alpha))
    field = fuse_narrow_band(grid, with_free, rule).field
    kept = largest_component(marching_cubes(field, grid.origin, grid.voxel))
    err = np.abs(np.linalg.norm(kept.vertices, axis=1) - RADIUS)
    assert err.max() < grid.voxel and err.mean() < 0.25 * grid.voxel
    hollow = fuse_narrow_band(grid, without, rule).field
    assert hollow[tuple(n // 2 for n in grid.shape)] > 0  # the centre is carved


def test_occluded_votes_keep_a_hole_seen_by_few_views_from_tunnelling_the_solid():
    """3 of 24 views see an empty disc through the sphere's centre (alpha 0: the whole ray is free, as a
    sparse-view model can be from a novel direction). The centre voxel lies far behind the surface every
    other view saw: unobserved by them, the three carve it (+1). With occluded_weight 0.25 (the weight
    chosen here) the 21 votes of −0.25 outweigh the three and it stays inside; the price is a bias of the
    surface outwards (a voxel just outside the far side is occluded too): mean radius within 0.25 voxel,
    every vertex within 0.75 voxel (weight 1: mean +1.2, max 3.1 voxels)."""
    grid = VoxelGrid.around(np.full(3, -1.0), np.full(3, 1.0), 48)
    views = []
    for k, c in enumerate(_cameras()):
        depth, alpha = sphere_depth(c, RADIUS)
        if k % 8 == 0:
            uv, _ = c.project(np.zeros((1, 3)))
            rows, cols = np.mgrid[: c.height, : c.width]
            hole = (cols + 0.5 - uv[0, 0]) ** 2 + (rows + 0.5 - uv[0, 1]) ** 2 < 6.0**2
            depth, alpha = np.where(hole, np.nan, depth), np.where(hole, 0.0, alpha)
        views.append(View(c, depth, alpha))
    centre = tuple(int(round(-o / grid.voxel)) for o in grid.origin)
    assert np.allclose(grid.origin + grid.voxel * np.array(centre), 0.0, atol=grid.voxel)
    tunnelled = fuse_views(grid, views, FusionRule(3.0 * grid.voxel, 0.5, 0.05, 0.0)).field
    assert tunnelled[centre] == 1.0
    rule = FusionRule(3.0 * grid.voxel, 0.5, 0.05, 0.25)
    field = fuse_views(grid, views, rule).field
    assert field[centre] < -0.2
    mesh = largest_component(marching_cubes(field, grid.origin, grid.voxel))
    err = np.linalg.norm(mesh.vertices, axis=1) - RADIUS
    assert 0.0 < err.mean() < 0.25 * grid.voxel and np.abs(err).max() < 0.75 * grid.voxel


def test_nan_depth_is_no_surface():
    """A median-depth map is NaN where the opacity never reaches 1/2: such pixels (alpha 0.2 here, above
    carve_alpha) say nothing, NaN never reaches the field, and the sphere's pixels alone give the sphere."""
    cams = _cameras()
    views = []
    for c in cams:
        depth, alpha = sphere_depth(c, RADIUS)
        views.append(View(c, np.where(alpha > 0, depth, np.nan), np.where(alpha > 0, 1.0, 0.2)))
    grid = VoxelGrid.around(np.full(3, -1.0), np.full(3, 1.0), 48)
    field = fuse_views(grid, views, FusionRule(3.0 * grid.voxel, 0.5, 0.05, 0.0)).field
    assert np.isfinite(field).all()
    mesh = largest_component(marching_cubes(field, grid.origin, grid.voxel))
    assert np.abs(np.linalg.norm(mesh.vertices, axis=1) - RADIUS).max() < grid.voxel


def test_clip_to_hull_is_the_intersection_with_the_visual_hull():
    """A solid filling the grid, clipped to the hull of a sphere (r 0.5) seen by 24 cameras: the surface is
    the hull's (outside the sphere by at most the hull's own excess, inside it by at most half a voxel); a
    small sphere (r 0.3) deep inside the hull is left unchanged."""
    cams = _cameras()
    masks = [sphere_depth(c, 0.5)[1] for c in cams]
    grid = VoxelGrid.around(np.full(3, -1.0), np.full(3, 1.0), 64)
    full = np.full(grid.shape, -1.0, np.float32)
    mesh = largest_component(marching_cubes(clip_to_hull(full, grid, cams, masks), grid.origin, grid.voxel))
    r = np.linalg.norm(mesh.vertices, axis=1)
    assert r.min() > 0.5 - 0.5 * grid.voxel and r.max() < 0.5 * 1.1
    centres = grid.centres().numpy().reshape(*grid.shape, 3)
    small = np.clip((np.linalg.norm(centres, axis=-1) - 0.3) / (3 * grid.voxel), -1, 1).astype(np.float32)
    assert np.array_equal(clip_to_hull(small, grid, cams, masks), small)


def test_narrow_band_fusion_gives_the_full_grid_surface():
    """The coarse-to-fine band changes nothing where the surface is: same face count within 0.5%, the
    two meshes within a tenth of a voxel of each other (Chamfer)."""
    band, voxel = _fused(lambda c: sphere_depth(c, RADIUS), band=True)
    full, _ = _fused(lambda c: sphere_depth(c, RADIUS), band=False)
    assert abs(len(band.faces) - len(full.faces)) <= 0.005 * len(full.faces)
    assert np.allclose(np.sort(np.linalg.norm(band.vertices, axis=1))[[0, -1]],
                       np.sort(np.linalg.norm(full.vertices, axis=1))[[0, -1]], atol=0.1 * voxel)  # fmt: skip


def test_largest_component_and_decimation():
    n = 48
    x = np.linspace(-1.5, 1.5, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    big = np.sqrt(X**2 + Y**2 + Z**2) - 0.8
    small = np.sqrt((X - 1.2) ** 2 + (Y - 1.2) ** 2 + (Z - 1.2) ** 2) - 0.15
    both = marching_cubes(np.minimum(big, small), np.full(3, -1.5), x[1] - x[0])
    one = largest_component(both)
    assert len(one.faces) < len(both.faces) and np.linalg.norm(one.vertices, axis=1).max() < 0.85
    light = decimate(one, 500)
    assert 400 <= len(light.faces) <= 500
    assert abs(light.volume() / one.volume() - 1) < 0.03


def test_hull_mesh_of_a_sphere_contains_it_and_is_close():
    """Masks of a sphere from 8 ring cameras: the hull mesh encloses the sphere (visual hulls only add
    volume) and its volume lies within 40% above the sphere's."""
    cams = ring_cameras(8, size=96)
    masks = [sphere_depth(c, RADIUS)[1] for c in cams]
    mesh = hull_mesh(cams, masks, resolution=64)
    sphere = 4 / 3 * np.pi * RADIUS**3
    assert 0.97 * sphere < mesh.volume() < 1.4 * sphere


def _coloured_sphere() -> TriMesh:
    n = 24
    x = np.linspace(-1.2, 1.2, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    mesh = marching_cubes(np.sqrt(X**2 + Y**2 + Z**2) - 1.0, np.full(3, -1.2), x[1] - x[0])
    mesh.colours = (0.5 + 0.5 * mesh.vertices).clip(0, 1).astype(np.float32)
    return mesh


def test_ply_and_glb_reload_with_the_same_counts(tmp_path):
    import trimesh

    mesh = _coloured_sphere()
    back = read_ply(write_ply(mesh, tmp_path / "m.ply"))
    assert np.allclose(back.vertices, mesh.vertices) and np.array_equal(back.faces, mesh.faces)
    assert np.abs(back.colours - mesh.colours).max() <= 0.5 / 255 + 1e-6
    glb = write_glb(mesh, tmp_path / "m.glb", up=np.array([0, 0, 1.0]), centre=np.zeros(3))
    scene = trimesh.load(glb, force="scene")
    loaded = list(scene.geometry.values())
    assert len(loaded) == 1
    assert len(loaded[0].vertices) == len(mesh.vertices) and len(loaded[0].faces) == len(mesh.faces)
    # +Z up became +Y up: the highest vertex now has the largest y
    assert np.isclose(loaded[0].vertices[:, 1].max(), mesh.vertices[:, 2].max(), atol=1e-5)


def _validator() -> tuple[str, str]:
    """(node, folder holding node_modules/gltf-validator), or a skip naming what is missing."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("needs node for the Khronos glTF validator (npm install -g gltf-validator)")
    roots = [str(Path(__file__).resolve().parents[1] / "js" / "node_modules")]  # js/: `npm ci` (CI does)
    npm = shutil.which("npm")
    if npm is not None:
        roots.append(subprocess.run([npm, "root", "-g"], capture_output=True, text=True).stdout.strip())
    for root in roots:
        if root and (Path(root) / "gltf-validator").is_dir():
            return node, root
    pytest.skip("needs the npm package gltf-validator (cd js && npm ci, or npm install -g gltf-validator)")


def _textured_sphere():
    from go_core.mesh.types import TexturedMesh

    mesh = _coloured_sphere()
    uvs = (0.5 + 0.5 * mesh.vertices[:, :2] / 1.2).clip(0, 1)  # any valid coordinates
    ramp = np.linspace(0, 255, 16, dtype=np.uint8)
    texture = np.stack(np.broadcast_arrays(ramp[:, None], ramp[None, :], np.uint8(128)), -1)
    return TexturedMesh(mesh.vertices, mesh.faces, uvs, np.ascontiguousarray(texture))


@pytest.mark.parametrize("kind", ["vertex_colours", "texture"])
def test_glb_passes_the_khronos_validator(tmp_path, kind):
    node, root = _validator()
    mesh = _coloured_sphere() if kind == "vertex_colours" else _textured_sphere()
    glb = write_glb(mesh, tmp_path / "m.glb", up=np.array([0, 0, 1.0]), centre=np.zeros(3))
    script = (
        "const v = require('gltf-validator'); const fs = require('fs');"
        "v.validateBytes(new Uint8Array(fs.readFileSync(process.argv[1])))"
        ".then(r => console.log(JSON.stringify(r.issues)))"
        ".catch(e => { console.error(e); process.exit(1); });"
    )
    env = {"NODE_PATH": root, "PATH": str(Path(node).parent)}
    out = subprocess.run([node, "-e", script, str(glb)], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    issues = json.loads(out.stdout)
    assert issues["numErrors"] == 0, issues["messages"]


def test_more_seen_views_than_fusion_views_is_an_error_before_any_work():
    """``seen_views`` above the number of fusion views would drop every face: refused up front, naming the
    settings, instead of a misleading 'see-through model' after the fusion."""
    from go_core.mesh.extract import mesh_from_gaussians
    from go_core.mesh.settings import MeshSettings

    settings = MeshSettings(seen_views=11, ellipse_views=4, sphere_views=6)
    box = (np.full(3, -1.0), np.full(3, 1.0))
    with pytest.raises(ValueError, match=r"mesh.seen_views 11 .* 10 fusion views"):
        mesh_from_gaussians(None, [], box, settings, masks=[])
