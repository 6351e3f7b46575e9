"""How much a support plane would take off the final mesh's error (issue 35): the fused field of a dev
scene's final model cut below a horizontal plane, at an estimated height and at the true one.

"Up" is the normal of the training cameras' ellipse (the glTF's +Y). The estimate is the ``--quantile`` of
the heights of the surface the training views see: their median depth back-projected at the pixels inside
the (3x3-eroded) training mask where the model's alpha is at least 1/2. The oracle is the lowest vertex of
the ground-truth mesh: the best any estimate of a flat support could do. Each cut mesh goes through the rest
of the mesh step (largest component, ``seen_views``, decimation) and is scored at ``--samples`` per surface.

    python benchmarks/archive/geometry_support_plane.py --data ../shared/data/dev \\
        --models benchmarks/results/repair_dev_prior2_ablations.json --variant realesr \\
        --scenes alphabet_soup --out benchmarks/results/geometry_support_plane.json   # --merge for more
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
from _final_models import final_gaussians, load_final  # benchmarks/ is on sys.path as a script
from _machine import code_version

from go_core.camera import fit_ellipse
from go_core.mesh.extract import fuse_gaussians, render_maps, surface
from go_core.mesh.settings import MeshSettings
from go_core.metrics.geometry import geometry_metrics


def seen_heights(g, cams, masks, up: np.ndarray, size: int) -> np.ndarray:
    """Heights along ``up`` of the surface the training views see (module docstring), all views together."""
    small = [c.scaled(size / max(c.width, c.height)) for c in cams]
    heights = []
    maps = render_maps(g, small, "auto", 4, "median")
    for c, mask, (_, z, alpha, _, _) in zip(small, masks, maps, strict=True):
        m = cv2.resize(np.asarray(mask, np.float32), (c.width, c.height), interpolation=cv2.INTER_AREA)
        m = cv2.erode((m > 0.5).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        sel = m & (alpha >= 0.5) & np.isfinite(z)
        v, u = np.nonzero(sel)
        k = np.asarray(c.K, np.float64)
        x, y = (u + 0.5 - k[0, 2]) / k[0, 0], (v + 0.5 - k[1, 2]) / k[1, 1]
        cam_pts = np.stack([x * z[sel], y * z[sel], z[sel]], 1)
        c2w = np.linalg.inv(np.asarray(c.world_to_cam, np.float64))
        heights.append((cam_pts @ c2w[:3, :3].T + c2w[:3, 3]) @ up)
    return np.concatenate(heights)


def measure(scene_dir: Path, gaussians: Path, quantile: float, samples: int) -> dict:
    final = load_final(scene_dir, gaussians)
    cams, masks, gt = final.cameras, final.masks, final.truth
    up = fit_ellipse(cams).normal
    s = MeshSettings()
    fused = fuse_gaussians(final.gaussians, cams, final.box, s, masks)
    grid, field, truncation = fused.grid, fused.tsdf.field, fused.rule.truncation
    axes = [grid.origin[i] + grid.voxel * np.arange(grid.shape[i]) for i in range(3)]
    height = sum(a * up[i] for i, a in enumerate(np.meshgrid(*axes, indexing="ij")))
    estimate = float(np.quantile(seen_heights(final.gaussians, cams, masks, up, s.max_size), quantile))
    planes = {"none": None, "estimate": estimate, "truth": float((gt.vertices @ up).min())}
    out = {"gaussians": str(gaussians), "truth_bottom": round(planes["truth"], 4), "cuts": {}}
    for name, h in planes.items():
        f = field if h is None else np.maximum(field, np.clip((h - height) / truncation, -1, 1))
        mesh = surface(fused, s, f.astype(field.dtype))[0]
        res = geometry_metrics(mesh, gt, samples, 0)
        out["cuts"][name] = {"height": None if h is None else round(h, 4)} | {
            k: round(float(res[k]), 4) for k in ("chamfer_l1", "accuracy", "completeness", "fscore_1pct")
        }
    return out


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--models", type=Path, required=True, help="a repair_dev.py JSON (repair_dir per scene)")
    ap.add_argument("--variant", default="realesr")
    ap.add_argument("--scenes", nargs="+", required=True)
    ap.add_argument("--quantile", type=float, default=0.005)
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--merge", action="store_true")
    args = ap.parse_args(argv)
    models = final_gaussians(args.models, args.variant)
    result = json.loads(args.out.read_text()) if args.merge else {
        "settings": {"quantile": args.quantile, "samples": args.samples, "seed": 0,
                     "models": f"{args.models} ({args.variant})"}, "commands": [], "scenes": {}}  # fmt: skip
    command = f"python benchmarks/archive/geometry_support_plane.py {' '.join(argv)}"
    result["commands"].append(f"{command} (code {code_version()})")
    for name in args.scenes:
        result["scenes"][name] = measure(args.data / name, models[name], args.quantile, args.samples)
        print(name, json.dumps(result["scenes"][name]), flush=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
