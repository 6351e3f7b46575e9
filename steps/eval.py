"""eval: render the test views of the final model and score them (paper protocol).

Final model = the repaired Gaussians when the repair step produced them, else the coarse ones
(``steps._common.final_model_path``). Ground truth is each test photo composited on white with its mask;
renders use a white background; PSNR / SSIM / LPIPS-vgg (the paper's, also ×100 as ``lpips_star``) /
LPIPS-alex over the full image, masked variants with ``masked: true``. Missing LPIPS weights are recorded
as unavailable (None), never replaced by another number.

Outputs: ``metrics.json`` (per view + mean), ``test_grid.png`` (rows: GT, render, error map; up to
``grid_views`` test views, thumbnails of at most ``thumb_size`` px) for the report.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from go_core.io.atomic import atomic_write, atomic_write_json
from go_core.metrics.evaluate import MetricSuite, composite, error_map, mean_metrics

METRICS_SCHEMA = "go-pipeline/metrics"


def _repair_model(inputs: dict[str, Path]) -> str:
    """Which repair model produced the result ("compact:<name> (fine-tuned)", "sd15 (...)"), or ""."""
    info_path = Path(inputs["repair"]) / "repair.json" if inputs.get("repair") else None
    if info_path is None or not info_path.exists():
        return ""
    info = json.loads(info_path.read_text())
    if info.get("status") != "ok":
        return ""
    model = str(info.get("repair_model", "sd15"))
    if model == "compact":
        model = f"compact:{info.get('compact_model', '')}"
    return f"{model} ({info.get('lora', '')})"


def _model_reason(inputs: dict[str, Path], used: str) -> str:
    if used == "repair":
        return f"repair ran: {_repair_model(inputs)}"
    repair = inputs.get("repair")
    if repair is None:
        return "no repair step in this pipeline"
    info = Path(repair) / "repair.json"
    if not info.exists():
        return "repair produced no repair.json"
    data = json.loads(info.read_text())
    return f"repair status {data.get('status')!r}: {data.get('reason', 'no reason given')}"


def render_views(gaussians, cameras, device: str = "cpu", backend: str = "auto") -> list[np.ndarray]:
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


def _thumb(img: np.ndarray, size: int) -> np.ndarray:
    from PIL import Image

    h, w = img.shape[:2]
    f = min(1.0, size / max(h, w))
    im = Image.fromarray(img if img.dtype == np.uint8 else (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8))
    return np.asarray(im.resize((max(1, round(w * f)), max(1, round(h * f))), Image.BILINEAR))


def grid_image(
    gts: list[np.ndarray], renders: list[np.ndarray], max_views: int, thumb_size: int
) -> np.ndarray:
    """uint8 grid: one column per view (evenly spread over the test set), rows GT / render / error map."""
    n = len(gts)
    idx = np.unique(np.linspace(0, n - 1, min(n, max_views)).round().astype(int)) if n else []
    cols = []
    for i in idx:
        rows = [
            _thumb(gts[i], thumb_size),
            _thumb(renders[i], thumb_size),
            _thumb(error_map(renders[i], gts[i]), thumb_size),
        ]
        cols.append(np.concatenate(rows, axis=0))
    if not cols:
        return np.full((thumb_size, thumb_size, 3), 255, np.uint8)
    height = max(c.shape[0] for c in cols)
    cols = [np.pad(c, ((0, height - c.shape[0]), (0, 2), (0, 0)), constant_values=255) for c in cols]
    return np.concatenate(cols, axis=1)


def evaluate_scene(
    scene, renders: list[np.ndarray], suite: MetricSuite, masked: bool, on_view=None
) -> list[dict]:
    """Per-view metric dicts for the scene's test views against ``renders`` (same order);
    ``on_view(row)`` after each view (progress)."""
    per_view = []
    for view, pred in zip(scene.test, renders, strict=True):
        gt = composite(view.image, view.mask, 1.0)
        row = {"name": view.name}
        row.update(suite.evaluate(pred, gt, view.mask, masked=masked))
        per_view.append(row)
        if on_view is not None:
            on_view(row)
    return per_view


def run(ctx, inputs: dict[str, Path], params: dict) -> None:
    from go_pipeline.steps._common import final_model_path
    from PIL import Image

    from go_core.gaussians import Gaussians
    from go_core.scene.artifact import load_scene_artifact

    scene = load_scene_artifact(inputs["scene"])
    if not scene.test:
        from go_core.errors import SceneError

        raise SceneError("the scene has no test views to evaluate", path=inputs["scene"])
    model_path, used = final_model_path(inputs)
    gaussians = Gaussians.load(model_path)
    reason = _model_reason(inputs, used)
    ctx.log.info("evaluating the %s model (%d Gaussians): %s", used, len(gaussians), reason)

    suite = MetricSuite.load(tuple(params.get("lpips_nets", ["vgg", "alex"])))
    for net, why in suite.unavailable.items():
        ctx.log.warning("LPIPS-%s unavailable: %s", net, why)

    t0 = time.perf_counter()
    renders = render_views(gaussians, scene.test_cameras, ctx.device, params.get("backend", "auto"))
    render_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    bar = ctx.progress(len(scene.test), "metrics of the test views")

    def advance(row: dict) -> None:
        bar.advance(1, **({"psnr": row["psnr"]} if row["psnr"] is not None else {}))

    per_view = evaluate_scene(scene, renders, suite, bool(params.get("masked", False)), on_view=advance)
    bar.close()
    metric_s = time.perf_counter() - t0
    mean = mean_metrics(per_view)

    result = {
        "schema": METRICS_SCHEMA,
        "version": 1,
        "model": used,
        "model_reason": reason,
        "repair_model": _repair_model(inputs) if used == "repair" else "",
        "num_gaussians": len(gaussians),
        "protocol": {
            "ground_truth": "test image composited on white with its mask",
            "render_background": "white",
            "region": "full image" + (" (+ masked metrics)" if params.get("masked") else ""),
            "ssim": "3DGS 11x11 Gaussian window, sigma 1.5, zero-padded borders",
            "lpips": "LPIPS v0.1 (lpips_vgg = the paper's LPIPS; lpips_star = 100 x lpips_vgg)",
        },
        "lpips_status": suite.status(),
        "device": ctx.device,
        "render_seconds": render_s,
        "metric_seconds": metric_s,
        "views": per_view,
        "mean": mean,
    }
    atomic_write_json(ctx.out_dir / "metrics.json", result)
    grid = grid_image(
        [composite(v.image, v.mask) for v in scene.test],
        renders,
        int(params.get("grid_views", 8)),
        int(params.get("thumb_size", 128)),
    )
    atomic_write(ctx.out_dir / "test_grid.png", lambda p: Image.fromarray(grid).save(p, format="PNG"))
    ctx.record(
        model=used,
        model_reason=reason,
        num_gaussians=len(gaussians),
        lpips=suite.status(),
        **{k: v for k, v in mean.items() if k != "masked"},
    )
