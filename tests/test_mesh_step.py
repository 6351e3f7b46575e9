"""The mesh step and eval's geometry on a Gaussian sphere whose true surface is known: the mesh is close to
the sphere and beats the visual hull of four views; the files and metrics.json say so."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from go_core import artifacts as art
from go_core.gaussians import Gaussians
from go_core.mesh.files import read_ply
from go_core.mesh.surface import marching_cubes
from go_core.mesh.views import fibonacci_directions
from go_core.render import render_camera
from go_core.scene.artifact import save_scene_artifact
from go_core.scene.types import Scene, View
from go_pipeline.pipeline import step_params
from tests._synthetic_depth import ring_cameras
from tests.test_coarse_steps import Ctx

pytestmark = pytest.mark.usefixtures("single_thread")
RADIUS, SIZE = 0.8, 64


def _sphere_gaussians() -> Gaussians:
    """Flat opaque discs (0.03 wide, 0.002 thick) tangent to the sphere: a thin shell whose surface is the
    sphere (isotropic blobs would put the visible surface about one scale outside it)."""
    normals = torch.as_tensor(fibonacci_directions(6000), dtype=torch.float32)
    colours = (0.5 + 0.4 * normals).clamp(0, 1)
    g = Gaussians.from_points(normals * RADIUS, colours, torch.full((len(normals),), 0.03), 0.95, 0)
    # the quaternion turning +z onto the normal: (1 + n_z, -n_y, n_x, 0), normalised
    q = torch.stack([1 + normals[:, 2], -normals[:, 1], normals[:, 0], torch.zeros(len(normals))], 1)
    g.quats = torch.nn.functional.normalize(q, dim=1)
    g.log_scales[:, 2] = float(np.log(0.002))
    return g


def _scene(root, g: Gaussians):
    views = []
    for cam in ring_cameras(6, size=SIZE, elevation_deg=25.0):
        with torch.no_grad():
            out = render_camera(g, cam)
        alpha = out.alpha[0, ..., 0].clamp(0, 1).numpy()
        rgb = (out.rgb[0] / out.alpha[0].clamp_min(1e-6)).clamp(0, 1).numpy()
        views.append(View(cam, rgb.astype(np.float32), alpha.astype(np.float32)))
    save_scene_artifact(Scene(root / "raw", "nerf", views[:4], views[4:]), root / "scene")
    n = 64
    x = np.linspace(-1.0, 1.0, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    truth = marching_cubes(np.sqrt(X**2 + Y**2 + Z**2) - RADIUS, np.full(3, -1.0), x[1] - x[0])
    np.savez(art.GT_MESH.path(root / "scene"), vertices=truth.vertices, faces=truth.faces)
    return root / "scene"


def test_mesh_step_and_eval_geometry(tmp_path):
    from go_pipeline.steps import eval as eval_step
    from go_pipeline.steps import mask, mesh

    g = _sphere_gaussians()
    inputs = {"scene": _scene(tmp_path, g), "repair": None}
    ctx = Ctx(tmp_path, "mask")
    mask.run(ctx, inputs, step_params(mask.__name__, {}))
    inputs["mask"] = ctx.out_dir
    (tmp_path / "coarse").mkdir()
    art.write_gaussians(tmp_path / "coarse", g)  # the model: the Gaussians the scene was rendered from
    inputs["coarse"] = tmp_path / "coarse"
    params = {"resolution": 64, "ellipse_views": 8, "sphere_views": 16, "max_size": 64, "hull_resolution": 64}
    ctx = Ctx(tmp_path, "mesh")
    mesh.run(ctx, inputs, step_params(mesh.__name__, params))
    out = read_ply(art.MESH_PLY.path(ctx.out_dir))
    r = np.linalg.norm(out.vertices, axis=1)
    assert abs(np.median(r) - RADIUS) < 0.03 and out.colours is not None
    assert ctx.records["source"] == "coarse" and ctx.records["faces"] == len(out.faces)
    info = json.loads(art.MESH_INFO.path(ctx.out_dir).read_text())
    assert info["views"] == 24 and "seconds" not in info  # timings stay out of the artifact
    again = Ctx(tmp_path, "mesh_again")
    mesh.run(again, inputs, step_params(mesh.__name__, params))
    for a in (art.MESH_PLY, art.MESH_GLB, art.HULL_MESH, art.MESH_INFO):  # deterministic bytes
        assert a.path(ctx.out_dir).read_bytes() == a.path(again.out_dir).read_bytes(), a.file
    inputs["mesh"] = ctx.out_dir

    ctx = Ctx(tmp_path, "eval")
    eval_params = {"lpips_nets": [], "geometry_samples": 100_000}
    eval_step.run(ctx, inputs, step_params(eval_step.__name__, eval_params))
    metrics = json.loads(art.METRICS.path(ctx.out_dir).read_text())
    geo = metrics["geometry"]
    assert geo["status"] == "ok" and geo["protocol"]["samples_per_surface"] == 100_000
    final, hull = geo["final"], geo["hull"]
    assert final["chamfer_l1"] < 0.5 * hull["chamfer_l1"] and final["fscore_2pct"] > hull["fscore_2pct"]
    assert final["silhouette_iou"] > 0.95 and len(final["silhouette_iou_per_view"]) == 2
    assert art.GEOMETRY_PICTURE.path(ctx.out_dir).is_file()
    # where the error is: the regions' squared errors add up to each view's PSNR, the inside pixels are
    # the true masks', and the 2 test views see surface that the 4 training views saw, and some they did not
    split = metrics["error_split"]
    assert split["status"] == "ok"
    scene = art.read_scene(inputs["scene"])
    for view, row, test in zip(metrics["views"], split["per_view"], scene.test, strict=True):
        sse = sum(row[r]["sse"] for r in ("outside", "seen", "unseen"))
        assert -10 * np.log10(sse / test.mask.size) == pytest.approx(view["psnr"], abs=1e-3)
        inside = row["seen"]["pixels"] + row["unseen"]["pixels"]
        assert inside == int((test.mask > 0.5).sum())
    regions = split["regions"]
    assert sum(regions[r]["error_share"] for r in regions) == pytest.approx(1.0)
    assert 0.5 < regions["seen"]["pixel_share"] / (1 - regions["outside"]["pixel_share"]) < 1.0
