"""eval: render the test views of the final model and score them (paper protocol).

Final model = the repaired Gaussians when the repair step produced them, else the coarse ones
(``go_core.artifacts.final_model``). Ground truth is each test photo composited on white with its mask;
renders use a white background; PSNR / SSIM / LPIPS-vgg (the paper's, also ×100 as ``lpips_star``) /
LPIPS-alex over the full image, masked variants with ``masked: true``. Missing LPIPS weights are recorded
as unavailable (None), never replaced by another number.

Outputs: ``metrics.json`` (per view + mean), ``test_grid.png`` (rows: GT, render, error map; up to
``grid_views`` test views, thumbnails of at most ``thumb_size`` px) for the report. When the scene carries
a ground-truth mesh and the mesh step ran, ``metrics.json`` has ``geometry`` (go_core.metrics.geometry:
Chamfer-L1, F@1%/2%, normal consistency, test-view silhouette IoU of the final mesh and of the visual
hull's mesh, the baseline) and ``geometry.png`` shows the ground truth, the final mesh and the hull mesh.
With a ground-truth mesh, ``error_split`` says where the test error is: outside the true silhouette, or on
surface that the training views see or do not see (go_core.metrics.error_split).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from go_core import artifacts as art
from go_core.io.atomic import atomic_write
from go_core.io.images import composite, thumbnail
from go_core.metrics.evaluate import MetricSuite, error_map, mean_metrics

if TYPE_CHECKING:
    from go_pipeline.steps.params import EvalParams

METRICS_SCHEMA = "go-pipeline/metrics"


def _repair_model(info: dict | None) -> str:
    """Which repair model produced the result ("compact:<name> (fine-tuned)", "sd15 (...)"), or ""."""
    if info is None or info.get("status") != art.STATUS_OK:
        return ""
    model = str(info.get("repair_model", "sd15"))
    if model == "compact":
        model = f"compact:{info.get('compact_model', '')}"
    return f"{model} ({info.get('lora', '')})"


def _model_reason(inputs: dict[str, Path], used: str, info: dict | None) -> str:
    if used == "repair":
        return f"repair ran: {_repair_model(info)}"
    if inputs.get("repair") is None:
        return "no repair step in this pipeline"
    if info is None:
        return f"repair produced no {art.REPAIR_INFO.file}"
    return f"repair status {info.get('status')!r}: {info.get('reason', 'no reason given')}"


def render_views(gaussians, cameras, device: str, backend: str) -> list[np.ndarray]:
    """Render each camera on a white background; float32 [H,W,3] numpy images."""
    import torch

    from go_core.render import render_camera

    g = gaussians.to(device=device, dtype=torch.float32)
    white = torch.ones(3, device=device)
    out = []
    with torch.no_grad():
        for cam in cameras:
            res = render_camera(g, cam, background=white, backend=backend)
            out.append(res.rgb[0].clamp(0, 1).cpu().numpy().astype(np.float32))
    return out


def grid_image(
    gts: list[np.ndarray], renders: list[np.ndarray], max_views: int, thumb_size: int
) -> np.ndarray:
    """uint8 grid: one column per view (evenly spread over the test set), rows GT / render / error map."""
    n = len(gts)
    idx = np.unique(np.linspace(0, n - 1, min(n, max_views)).round().astype(int)) if n else []
    cols = []
    for i in idx:
        rows = [
            thumbnail(gts[i], thumb_size),
            thumbnail(renders[i], thumb_size),
            thumbnail(error_map(renders[i], gts[i]), thumb_size),
        ]
        cols.append(np.concatenate(rows, axis=0))
    if not cols:
        return np.full((thumb_size, thumb_size, 3), 255, np.uint8)
    height = max(c.shape[0] for c in cols)
    cols = [np.pad(c, ((0, height - c.shape[0]), (0, 2), (0, 0)), constant_values=255) for c in cols]
    return np.concatenate(cols, axis=1)


def ground_truths(scene) -> list[np.ndarray]:
    """The scene's test photos composited on white with their masks (the paper's ground truth)."""
    return [composite(view.image, view.mask, 1.0) for view in scene.test]


def evaluate_scene(
    scene,
    renders: list[np.ndarray],
    suite: MetricSuite,
    masked: bool,
    on_view=None,
    gts: list[np.ndarray] | None = None,
) -> list[dict]:
    """Per-view metric dicts for the scene's test views against ``renders`` (same order);
    ``on_view(row)`` after each view (progress); ``gts`` are their ground truths when already computed
    (``ground_truths``)."""
    gts = ground_truths(scene) if gts is None else gts
    per_view = []
    for view, pred, gt in zip(scene.test, renders, gts, strict=True):
        row = {"name": view.name}
        row.update(suite.evaluate(pred, gt, view.mask, masked=masked))
        per_view.append(row)
        if on_view is not None:
            on_view(row)
    return per_view


def cf_test_cameras(inputs: dict[str, Path], scene, gaussians, gts, params: EvalParams, ctx):
    """The test cameras to render, and how they were obtained (``metrics.json`` ``poses``).

    Given poses: the scene's test cameras. A model fitted with estimated (scene.poses) or refined
    (coarse.refine_poses) training poses lives in the frame of its cameras (coarse ``cameras.json``), so its
    metrics are CF metrics: the test cameras are mapped by the similarity from the scene folder's own
    training poses onto those cameras, then each is fitted to its photo for ``test_pose_iterations`` with
    the model frozen (the paper's CF protocol)."""
    import torch

    from go_core.poses.refine import refine_pose
    from go_core.poses.similarity import similarity_from_cameras

    has_cameras = art.CAMERAS.path(inputs["coarse"]).is_file()  # a coarse step of your own may not write it
    refined = has_cameras and art.read_json(inputs["coarse"], art.CAMERAS)["refined"]
    if not refined and not art.poses_estimated(inputs["scene"]):
        return scene.test_cameras, {"cf": False, "test": "given"}
    given = art.read_given_train_cameras(inputs["scene"])
    sim = similarity_from_cameras(given, art.read_cameras(inputs["coarse"]))
    cameras = [sim.camera(c) for c in scene.test_cameras]
    if params.test_pose_iterations > 0:
        g = gaussians.to(dtype=torch.float32)
        bar = ctx.progress(len(cameras), "test-view pose fits (CF protocol)")
        fitted = []
        for cam, gt in zip(cameras, gts, strict=True):
            target = torch.as_tensor(np.asarray(gt, np.float32))
            fitted.append(
                refine_pose(g, cam, target, iterations=params.test_pose_iterations, backend=params.backend)[0]
            )
            bar.advance(1)
        bar.close()
        cameras = fitted
    return cameras, {
        "cf": True,
        "test": "CF: similarity from the given onto the fitted training cameras, then a per-view pose fit "
        f"({params.test_pose_iterations} iterations, model frozen)",
        "similarity_scale": sim.scale,
    }


def geometry(inputs: dict[str, Path], scene, cf: bool, params: EvalParams, ctx) -> dict | None:
    """The ``geometry`` entry of metrics.json (and geometry.png), or a reason why there is none."""
    import torch
    from PIL import Image

    from go_core.mesh.files import read_mesh_npz, read_ply
    from go_core.mesh.picture import shaded
    from go_core.metrics.geometry import score_meshes

    mesh_dir = inputs.get("mesh")
    if mesh_dir is None or not art.MESH_PLY.path(mesh_dir).is_file():
        return {"status": art.STATUS_SKIPPED, "reason": "no mesh step in this pipeline"}
    if not art.GT_MESH.path(inputs["scene"]).is_file():
        return {"status": art.STATUS_SKIPPED, "reason": f"the scene has no ground-truth {art.GT_MESH.file}"}
    if cf:
        return {"status": art.STATUS_SKIPPED, "reason": "the model lives in its fitted cameras' frame (CF)"}
    gt = read_mesh_npz(art.GT_MESH.path(inputs["scene"]))
    meshes = {"final": read_ply(art.MESH_PLY.path(mesh_dir)), "hull": read_ply(art.HULL_MESH.path(mesh_dir))}
    masks = [v.mask if v.mask is not None else np.ones((v.camera.height, v.camera.width)) for v in scene.test]
    res = score_meshes(
        meshes, gt, scene.test_cameras, masks, params.geometry_samples, int(ctx.seed), torch.get_num_threads()
    )  # the step's threads share the queries; the figures do not depend on how many
    cam = scene.test_cameras[0]
    picture = np.concatenate(
        [shaded(gt, cam), shaded(meshes["final"], cam, use_colours=True), shaded(meshes["hull"], cam)], axis=1
    )
    atomic_write(
        art.GEOMETRY_PICTURE.path(ctx.out_dir), lambda p: Image.fromarray(picture).save(p, format="PNG")
    )
    return {"status": art.STATUS_OK, **res}


def error_split(inputs: dict[str, Path], scene, renders: list, gts: list, cf: bool) -> dict:
    """The ``error_split`` entry of metrics.json (go_core.metrics.error_split): the test views' squared
    error split between pixels outside the true silhouette and on surface that a training view sees or
    that none sees, from the scene's ground-truth mesh; or a reason why there is none."""
    from go_core.mesh.files import read_mesh_npz
    from go_core.metrics.error_split import SUPERSAMPLE, SeenSurface, split_errors, summarise

    if not art.GT_MESH.path(inputs["scene"]).is_file():
        return {"status": art.STATUS_SKIPPED, "reason": f"the scene has no ground-truth {art.GT_MESH.file}"}
    if cf:
        return {"status": art.STATUS_SKIPPED, "reason": "the model lives in its fitted cameras' frame (CF)"}
    if any(v.mask is None for v in scene.test):
        return {"status": art.STATUS_SKIPPED, "reason": "a test view has no mask (the true silhouette)"}
    surface = SeenSurface(read_mesh_npz(art.GT_MESH.path(inputs["scene"])), scene.train_cameras)
    per_view = [
        split_errors(pred, gt, surface.regions(cam, view.mask))
        for view, cam, pred, gt in zip(scene.test, scene.test_cameras, renders, gts, strict=True)
    ]
    return {
        "status": art.STATUS_OK,
        "regions": summarise(per_view),
        "definition": "outside: true alpha <= 0.5; seen / unseen: inside, at a ground-truth surface point "
        f"that a training view sees (its face map at {SUPERSAMPLE}x resolution has a face whose plane "
        f"passes within {surface.tolerance:.4g} of the point) or that none sees",
        "per_view": [{"name": v.name, **split} for v, split in zip(scene.test, per_view, strict=True)],
    }


def run(ctx, inputs: dict[str, Path], params: EvalParams) -> None:
    from PIL import Image

    scene = art.read_scene(inputs["scene"])
    if not scene.test:
        from go_core.errors import SceneError

        raise SceneError("the scene has no test views to evaluate", path=inputs["scene"])
    final = art.final_model(inputs["coarse"], inputs.get("repair"))  # reads repair.json once
    gaussians, used = art.read_gaussians(final.folder), final.source
    reason = _model_reason(inputs, used, final.repair_info)
    ctx.log.info("evaluating the %s model (%d Gaussians): %s", used, len(gaussians), reason)

    suite = MetricSuite.load(tuple(params.lpips_nets))
    for net, why in suite.unavailable.items():
        ctx.log.warning("LPIPS-%s unavailable: %s", net, why)

    gts = ground_truths(scene)
    test_cameras, poses = cf_test_cameras(inputs, scene, gaussians, gts, params, ctx)
    t0 = time.perf_counter()
    renders = render_views(gaussians, test_cameras, ctx.device, params.backend)
    render_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    bar = ctx.progress(len(scene.test), "metrics of the test views")

    def advance(row: dict) -> None:
        bar.advance(1, **({"psnr": row["psnr"]} if row["psnr"] is not None else {}))

    per_view = evaluate_scene(scene, renders, suite, params.masked, on_view=advance, gts=gts)
    bar.close()
    metric_s = time.perf_counter() - t0
    mean = mean_metrics(per_view)

    result = {
        "schema": METRICS_SCHEMA,
        "version": 1,
        "model": used,
        "model_reason": reason,
        "repair_model": _repair_model(final.repair_info) if used == "repair" else "",
        "num_gaussians": len(gaussians),
        "protocol": {
            "ground_truth": "test image composited on white with its mask",
            "render_background": "white",
            "region": "full image" + (" (+ masked metrics)" if params.masked else ""),
            "ssim": "3DGS 11x11 Gaussian window, sigma 1.5, zero-padded borders",
            "lpips": "LPIPS v0.1 (lpips_vgg = the paper's LPIPS; lpips_star = 100 x lpips_vgg)",
        },
        "poses": poses,
        "lpips_status": suite.status(),
        "device": ctx.device,
        "views": per_view,
        "mean": mean,
        "geometry": geometry(inputs, scene, bool(poses.get("cf")), params, ctx),
        "error_split": error_split(inputs, scene, renders, gts, bool(poses.get("cf"))),
    }
    art.write_json(ctx.out_dir, art.METRICS, result)
    grid = grid_image(
        gts,
        renders,
        params.grid_views,
        params.thumb_size,
    )
    atomic_write(art.TEST_GRID.path(ctx.out_dir), lambda p: Image.fromarray(grid).save(p, format="PNG"))
    ctx.record(
        model=used,
        model_reason=reason,
        num_gaussians=len(gaussians),
        lpips=suite.status(),
        # timings go to the manifest, not metrics.json: artifacts are byte-identical across runs
        render_seconds=round(render_s, 3),
        metric_seconds=round(metric_s, 3),
        **{k: v for k, v in mean.items() if k != "masked"},
    )
