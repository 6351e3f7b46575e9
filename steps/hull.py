"""hull: the initial Gaussians — the visual hull of the training masks (paper Sec. 3.3), or, as the
vanilla-3DGS ablation (``init: random``), uniformly random points with random colours in a cube around the
cameras' look-at point whose size follows from the cameras' field of view (so no mask information is used).

Outputs ``gaussians.npz`` (go_core.gaussians) and ``hull.json`` (point count, bounding box, volume estimate).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from go_core import artifacts as art
from go_core.camera import look_at_point
from go_core.hull import points_to_gaussians, random_init, visual_hull

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


def run(ctx, inputs: dict[str, Path], params: HullParams) -> None:
    init = params.init
    scene = art.read_scene(inputs["scene"])
    cams = scene.train_cameras
    masks = art.read_masks(inputs["mask"], len(cams))
    images = [v.image for v in scene.train]
    num, opacity = params.num_points, params.opacity
    info: dict = {"init": init}
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
