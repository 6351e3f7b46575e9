"""A coarse model trained on a dev scene with pipeline.yaml's params, and its test-view scores: shared by
``geometry_dev.py`` and the archived ``archive/coarse_dev.py``.

Test renders use a white background; the ground truth is the test photo composited on white with its mask
(paper protocol). ``train_coarse``'s budget scales every step-based schedule
(``CoarseConfig.scaled_schedule``).
"""

from __future__ import annotations

import functools
import math
import time
from pathlib import Path

import numpy as np
import torch

from go_core.coarse.hull import points_to_gaussians, random_init, visual_hull
from go_core.coarse.loop import TrainView, optimize
from go_core.coarse.losses import ssim
from go_core.io.images import composite
from go_core.render import render_camera
from go_core.seeding import torch_generator
from go_pipeline.pipeline import step_params

DEV = Path(__file__).resolve().parents[3] / "shared" / "data" / "dev"


def step_params_from_yaml(step: str, profile: str | None) -> dict:
    """One step's resolved params from pipeline.yaml (with ``profile``)."""
    from go_pipeline.pipeline import load_pipeline

    return dict(load_pipeline().resolve_params(profile=profile)[step])


def coarse_params(profile: str | None, iterations: int) -> dict:
    """The coarse step's params from pipeline.yaml (with ``profile``), at the budget ``iterations``."""
    return {**step_params_from_yaml("coarse", profile), "iterations": iterations}


def hull_params(profile: str | None) -> dict:
    """The hull step's params from pipeline.yaml (with ``profile``): init points, carving, opacity."""
    return step_params_from_yaml("hull", profile)


def parse_overrides(items: list[str]) -> dict:
    """``["name=value", ...]`` (YAML values, parsed as the CLI's ``--set``) → {name: value}."""
    from go_pipeline.pipeline import parse_set_argument

    return dict(parse_set_argument(item) for item in items)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 10.0 * math.log10(1.0 / max(mse, 1e-12))


@functools.cache
def _lpips_vgg():
    """LPIPS-vgg (the paper's LPIPS; x100 = LPIPS*) from the cache, or None without weights."""
    from go_core.errors import MissingWeightsError
    from go_core.metrics.lpips import LPIPS

    try:
        return LPIPS.from_cache("vgg")
    except MissingWeightsError:
        return None


def evaluate(g, scene) -> dict:
    """Test-view PSNR/SSIM/LPIPS* on white, plus where the error is: silhouette IoU (rendered alpha > 0.5 vs
    the true mask) and the share of squared error on pixels outside the true silhouette."""
    white = torch.ones(3)
    lpips = _lpips_vgg()
    from go_core.coarse.regularizers import eroded_mask

    ps, ss, lp, ious, outside, holes = [], [], [], [], [], []
    with torch.no_grad():
        for v in scene.test:
            cam = v.camera
            out = render_camera(g, cam, background=white)
            pred = out.rgb[0].clamp(0, 1)
            gt = torch.from_numpy(composite(v.image, v.mask, 1.0))
            ps.append(psnr(pred.numpy(), gt.numpy()))
            ss.append(float(ssim(pred, gt)))
            if lpips is not None:
                a, b = (t.permute(2, 0, 1)[None] * 2 - 1 for t in (pred, gt))
                lp.append(100.0 * float(lpips(a, b)[0]))
            if v.mask is not None:
                m = np.asarray(v.mask) > 0.5
                a = out.alpha[0, ..., 0].numpy() > 0.5
                ious.append(float((a & m).sum() / max((a | m).sum(), 1)))
                interior = eroded_mask(torch.as_tensor(np.asarray(v.mask, np.float32)), 2).numpy() > 0.5
                holes.append(float((~a[interior]).mean()) if interior.any() else 0.0)
                se = ((pred.numpy().astype(np.float64) - gt.numpy()) ** 2).sum(-1)
                outside.append(float(se[~m].sum() / max(se.sum(), 1e-12)))
    res = {
        "psnr": float(np.mean(ps)),
        "ssim": float(np.mean(ss)),
        "psnr_per_view": [round(p, 3) for p in ps],
    }
    if lp:
        res["lpips_star"] = float(np.mean(lp))
    if ious:
        res["silhouette_iou"] = round(float(np.mean(ious)), 4)
        res["error_share_outside_silhouette"] = round(float(np.mean(outside)), 4)
        # share of the mask interior (eroded 2 px) rendered with alpha < 0.5: see-through holes
        res["see_through_pct"] = round(100 * float(np.mean(holes)), 3)
    return res


def initial_points(scene, init: str, seed: int, hull: dict, random_points: int):
    """The initial points and colours: the visual hull (``init`` "hull", the hull step's ``hull`` params) or
    vanilla 3DGS's random box (``init`` "random", ``random_points`` of them)."""
    cams = scene.train_cameras
    if init == "hull":
        masks, images = [v.mask for v in scene.train], [v.image for v in scene.train]
        res = visual_hull(
            cams,
            masks,
            images,
            num_points=hull["num_points"],
            all_but_one=hull["all_but_one"],
            threshold=hull["mask_threshold"],
            seed=seed,
        )
        return res.points, res.colors
    from go_pipeline.steps.hull import random_box

    lo, hi = random_box(cams)
    return random_init(lo, hi, random_points, seed=seed)


def train_coarse(
    scene,
    init: str,
    iterations: int,
    seed: int,
    overrides: dict,
    random_points: int = 20_000,
    base: dict | None = None,
    hull: dict | None = None,
):
    """Train one coarse model on one scene from ``init`` ("hull" or "random"); ``base`` the coarse params and
    ``hull`` the hull step's (default: pipeline.yaml's defaults), ``overrides`` on top of ``base``. Returns
    (Gaussians, training stats, a dict of params and seconds)."""
    hull = hull or hull_params(None)
    t0 = time.process_time()
    pts, cols = initial_points(scene, init, seed, hull, random_points)
    init_g = points_to_gaussians(pts, cols, opacity=hull["opacity"])
    t_init = time.process_time() - t0
    params = {**(base or coarse_params(None, iterations)), "iterations": iterations, **overrides}
    config = step_params("go_pipeline.steps.coarse", params).scaled_schedule()
    views = [TrainView.from_arrays(v.camera, v.image, v.mask) for v in scene.train]
    t1, w1 = time.process_time(), time.perf_counter()
    g, stats = optimize(init_g, views, config, generator=torch_generator(seed))
    run = {
        "init_cpu_s": round(t_init, 2),
        "coarse_cpu_s": round(time.process_time() - t1, 2),
        "coarse_wall_s": round(time.perf_counter() - w1, 2),
        "params": params,
        "config": config.to_dict(),
    }
    return g, stats, run
