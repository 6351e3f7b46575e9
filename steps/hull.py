"""hull: the initial Gaussians — the visual hull of the training masks (paper Sec. 3.3), or, as the
vanilla-3DGS ablation (``init: random``), uniformly random points with random colours in a cube around the
cameras' look-at point whose size follows from the cameras' field of view (so no mask information is used).

Outputs ``gaussians.npz`` (go_core.gaussians) and ``hull.json`` (point count, bounding box, volume estimate);
with ``align_poses`` first turns and moves the training cameras until their silhouettes agree
(go_core.poses.silhouette_align: poses from another source are rarely exact) and writes them as
``cameras.json``, which coarse starts from.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from go_core import artifacts as art
from go_core.camera import look_at_point
from go_core.coarse.hull import points_to_gaussians, random_init, visual_hull

if TYPE_CHECKING:
    from go_pipeline.steps.params import HullParams


def random_box(cameras) -> tuple[np.ndarray, np.ndarray]:
    """Cube around the look-at point: half-size = mean camera distance × tan(half the narrower FOV)."""
    target = look_at_point(cameras)
    halves = []
    for c in cameras:
        dist = float(np.linalg.norm(c.center - target))
        tan_half = min(c.width / (2 * c.K[0, 0]), c.height / (2 * c.K[1, 1]))
        halves.append(dist * tan_half)
    half = float(np.mean(halves))
    return target - half, target + half


def _aligned_cameras(ctx, cams, masks, params: HullParams, info: dict):
    """hull.align_poses: the training cameras turned until their silhouettes agree
    (go_core.poses.silhouette_align), written as ``cameras.json`` for coarse; coverage before/after and the
    turns go to ``hull.json``."""
    from go_core.coarse.hull import hull_bounds
    from go_core.errors import SceneError
    from go_core.poses.silhouette_align import SilhouetteAlignSettings, align_cameras

    if len(cams) < 3:
        raise SceneError(f"hull.align_poses needs at least 3 training views, the scene has {len(cams)}")
    box = hull_bounds(cams, masks, min_views=len(cams) - 1, threshold=params.mask_threshold)
    settings = SilhouetteAlignSettings(
        iterations=params.align_iterations,
        centre_sigma=params.align_centre_sigma,
        rotation_sigma_deg=params.align_rotation_sigma,
    )
    res = align_cameras(cams, masks, box, settings)
    art.write_cameras(ctx.out_dir, res.cameras, aligned=True)
    info["aligned"] = {
        "turned_deg": [round(x, 4) for x in res.rotations_deg],
        "moved": [round(x, 5) for x in res.moved],
        "coverage_before": [round(x, 4) for x in res.coverage_before],
        "coverage_after": [round(x, 4) for x in res.coverage_after],
    }
    ctx.log.info(
        "hull: cameras turned by %s° and moved by %s %% of their distance (silhouette coverage %.3f → %.3f)",
        ", ".join(f"{x:.2f}" for x in res.rotations_deg),
        ", ".join(f"{100 * x:.1f}" for x in res.moved),
        min(res.coverage_before),
        min(res.coverage_after),
    )
    return res.cameras


def run(ctx, inputs: dict[str, Path], params: HullParams) -> None:
    init = params.init
    scene = art.read_scene(inputs["scene"])
    cams = scene.train_cameras
    masks = art.read_masks(inputs["mask"], len(cams))
    images = [v.image for v in scene.train]
    num, opacity = params.num_points, params.opacity
    info: dict = {"init": init}
    if params.align_poses:
        cams = _aligned_cameras(ctx, cams, masks, params, info)
    if init == "hull":
        res = visual_hull(
            cams,
            masks,
            images,
            num_points=num,
            all_but_one=params.all_but_one,
            threshold=params.mask_threshold,
            seed=ctx.seed,
        )
        points, colors = res.points, res.colors
        info.update(
            bbox_min=res.bbox_min.tolist(),
            bbox_max=res.bbox_max.tolist(),
            volume=res.volume,
            samples=res.samples,
            min_views=res.min_views,
        )
    else:
        lo, hi = random_box(cams)
        points, colors = random_init(lo, hi, params.random_points, seed=ctx.seed)
        info.update(bbox_min=lo.tolist(), bbox_max=hi.tolist())
    g = points_to_gaussians(points, colors, opacity=opacity, sh_degree=0)
    art.write_gaussians(ctx.out_dir, g)
    info["points"] = len(g)
    art.write_json(ctx.out_dir, art.HULL_INFO, info)
    ctx.record(**{k: v for k, v in info.items() if k in ("init", "points", "volume")})
