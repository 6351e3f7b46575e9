"""Where a final model puts the surface, view by view (issue 35): at each training and test camera of a dev
scene, the model's depth where its accumulated opacity reaches a level (0.5 is the mesh step's median
depth) against the ground-truth mesh's depth at the same pixel (go_core.metrics.error_split.depth_map),
over the pixels the truth covers. A model that fits the photos but is translucent at its surface reaches
0.5 behind the true surface: the depth the mesh step fuses lies inside the object there.

    python benchmarks/archive/depth_vs_truth.py --data ../shared/data/dev --models MODELS.json \\
        --variant default --scenes alphabet_soup --out benchmarks/results/depth_vs_truth.json

MODELS.json is a ``repair_dev.py`` JSON (a ``repair_dir`` per scene and variant), as for
benchmarks/archive/mesh_settings_final.py.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from _final_models import add_model_arguments, final_gaussians, load_final  # benchmarks/ on sys.path
from _machine import code_version, cpu_name

from go_core.metrics.error_split import depth_map
from go_core.render.api import render_median_depth

LEVELS = (0.1, 0.3, 0.5)
PERCENTILES = (10, 25, 50, 75, 90)


def view_record(gaussians, camera, truth, tolerance: float) -> dict:
    """One camera: the truth's pixel count, and per opacity level the share of them where the model's depth
    is more than ``tolerance`` behind / in front of the truth's, never reaches the level, and percentiles
    of the difference (model − truth, world units)."""
    true_depth = depth_map(truth, camera)
    covered = np.isfinite(true_depth)
    viewmat, K = camera.viewmat_tensor()[None], camera.K_tensor()[None]
    out: dict = {"pixels": int(covered.sum())}
    for level in LEVELS:
        z = render_median_depth(gaussians, viewmat, K, camera.width, camera.height, level=level)
        diff = z.numpy()[0][covered] - true_depth[covered]
        finite = np.isfinite(diff)
        out[f"level_{level}"] = {
            "behind": round(float(np.mean(diff[finite] > tolerance)), 4),
            "in_front": round(float(np.mean(diff[finite] < -tolerance)), 4),
            "never": round(float(np.mean(~finite)), 4),
            "percentiles": [round(float(p), 4) for p in np.percentile(diff[finite], PERCENTILES)],
        }
    return out


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_model_arguments(ap, "full")
    ap.add_argument("--scenes", nargs="+", required=True)
    ap.add_argument("--tolerance", type=float, default=0.05, help="world units (dev radius 1)")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    models = final_gaussians(args.models, args.variant)
    result = {
        "command": f"python benchmarks/archive/depth_vs_truth.py {' '.join(argv)} (code {code_version()})",
        "machine": cpu_name(),
        "levels": list(LEVELS),
        "percentiles": list(PERCENTILES),
        "tolerance": args.tolerance,
        "scenes": {},
    }
    for name in args.scenes:
        final = load_final(args.data / name, models[name])
        result["scenes"][name] = {
            "gaussians": str(models[name]),
            **{
                split: [view_record(final.gaussians, cam, final.truth, args.tolerance) for cam in cams]
                for split, cams in (("train", final.scene.train_cameras), ("test", final.scene.test_cameras))
            },
        }
        train = result["scenes"][name]["train"]
        print(name, "behind at 0.5, training views:", [v["level_0.5"]["behind"] for v in train], flush=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
