"""Which pretrained restorer repairs coarse renders best? (docs/repair.md, "Choosing the compact model")

For each scene work dir (``go-pipeline run SCENE --workdir W --until coarse`` first), renders the coarse
model at the scene's test views and scores, against the test photos on white: the coarse render itself, a
plain area-down/bilinear-up of it (the resampling alone, no network), and every compact model of
``go_core.compact.weights.MODELS`` used as a restorer (down by its scale, network back up), all untuned.
The test views are only scored here, never trained on. CPU seconds per restored view are reported too.

    python benchmarks/archive/compact_choice.py --workdirs /tmp/runs/milk ... \
        --out benchmarks/results/compact_choice.json
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from go_core.compact.restorer import CompactRestorer
from go_core.compact.weights import MODELS
from go_core.gaussians import Gaussians
from go_core.metrics.evaluate import MetricSuite, composite, mean_metrics
from go_core.repair.data import render_rgb_alpha
from go_core.scene.artifact import load_scene_artifact


def newest(workdir: Path, step: str) -> Path:
    dirs = [d for d in (workdir / "artifacts" / step).iterdir() if d.is_dir()]
    return max(dirs, key=lambda d: d.stat().st_mtime)


def resample(x: torch.Tensor, s: int) -> torch.Tensor:
    h, w = x.shape[-2:]
    small = F.interpolate(x, size=(h // s, w // s), mode="area")
    return F.interpolate(small, size=(h, w), mode="bilinear", align_corners=False)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workdirs", type=Path, nargs="+", required=True)
    ap.add_argument("--models", nargs="*", default=sorted(MODELS))
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    suite = MetricSuite.load(("vgg",))
    restorers = {name: CompactRestorer.load(name).eval() for name in args.models}
    for name in args.models:
        if "x4plus" not in name:  # 16 x the pixels of down_up for x4: too slow for RRDBNet on a CPU
            restorers[f"{name}:up_down"] = CompactRestorer.load(name, mode="up_down").eval()
    result: dict = {
        "machine": platform.processor() or platform.machine(),
        "threads": args.threads,
        "scenes": {},
    }
    for wd in args.workdirs:
        scene = load_scene_artifact(newest(wd, "scene"))
        g = Gaussians.load(newest(wd, "coarse") / "gaussians.npz")
        gts = [composite(v.image, v.mask) for v in scene.test]
        renders = [render_rgb_alpha(g, cam, 1.0)[0] for cam in scene.test_cameras]
        variants: dict[str, list[np.ndarray]] = {"coarse": [r.numpy() for r in renders]}
        seconds: dict[str, float] = {}
        for s in (2, 4):
            variants[f"resample_x{s}"] = [
                resample(r.permute(2, 0, 1)[None], s)[0].permute(1, 2, 0).numpy() for r in renders
            ]
        for name, model in restorers.items():
            t0 = time.process_time()
            with torch.no_grad():
                variants[name] = [
                    model.restore(r.permute(2, 0, 1)[None])[0].permute(1, 2, 0).numpy() for r in renders
                ]
            seconds[name] = (time.process_time() - t0) / len(renders)
        rows = {}
        for key, imgs in variants.items():
            per_view = [suite.evaluate(p, gt) for p, gt in zip(imgs, gts, strict=True)]
            m = mean_metrics(per_view)
            rows[key] = {"psnr": m["psnr"], "ssim": m["ssim"], "lpips_star": m["lpips_star"],
                         "cpu_s_per_view": seconds.get(key)}  # fmt: skip
            print(
                f"{wd.name:14s} {key:34s} PSNR {m['psnr']:.3f} SSIM {m['ssim']:.4f} "
                f"LPIPS* {m['lpips_star']:.3f}",
                flush=True,
            )
        result["scenes"][wd.name] = rows
    names = list(next(iter(result["scenes"].values())))
    result["mean"] = {
        k: {
            m: float(np.mean([result["scenes"][s][k][m] for s in result["scenes"]]))
            for m in ("psnr", "ssim", "lpips_star")
        }
        for k in names
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
