"""Photo working size: speed against error on one common footing (issue 32, item 5).

Test metrics of a run are taken at its own working size (``scene.photo_size``), so a run at 320 px and one at
512 px are not scored on the same images. This scores the final model of every given run on the test
photos of ONE run (its scene artifact: the photos undistorted at that run's size, composited on white with
its masks, and its test cameras). The runs share their SfM (``scene.sfm_size`` does not depend on the photo
size, and SfM repeats exactly on one thread), which is checked: the training cameras of every run must
equal the scoring run's up to the image scale.

    python benchmarks/archive/photos_sizes.py --score-on /tmp/gpb320/product/photos \\
        --run 320=/tmp/gpb320/product/photos --run 512=/tmp/gpb512/product/photos

Writes ``benchmarks/results/photos_sizes_ethiopian_head.json``: per run its wall time and step times (from
its ``.go/runs/last.json``) and PSNR / SSIM / LPIPS-vgg on the common test photos.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/ (photos.py), from archive/
from photos import last_run, step_artifact  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "results" / "photos_sizes_ethiopian_head.json"


def _same_poses(a: list, b: list) -> float:
    """Largest difference of the world-to-camera matrices (rotation and normalised translation)."""
    return max(float(np.abs(x.world_to_cam - y.world_to_cam).max()) for x, y in zip(a, b, strict=True))


def score(model_run: Path, scene, cameras, suite) -> dict:
    """Metrics of ``model_run``'s final model on ``scene``'s test photos (cameras at their size)."""
    from go_pipeline.steps.eval import evaluate_scene, ground_truths, render_views

    from go_core import artifacts as art
    from go_core.metrics.evaluate import mean_metrics

    last = last_run(model_run)
    final = art.final_model(step_artifact(last, "coarse"), step_artifact(last, "repair"))
    gaussians = art.read_gaussians(final.folder)
    renders = render_views(gaussians, cameras, "cpu", "auto")
    per_view = evaluate_scene(scene, renders, suite, masked=False, gts=ground_truths(scene))
    mean = mean_metrics(per_view)
    return {
        "model": final.source,
        "gaussians": len(gaussians),
        **{k: mean[k] for k in ("psnr", "ssim", "lpips_vgg")},
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--score-on", type=Path, required=True, help="the photo folder whose test photos score")
    p.add_argument("--run", action="append", required=True, help="LABEL=PHOTO_FOLDER (a finished run)")
    p.add_argument("--out", type=Path, default=OUT)
    args = p.parse_args()

    from go_core import artifacts as art
    from go_core.metrics.evaluate import MetricSuite
    from go_core.scene.artifact import load_scene_cameras

    scene_dir = step_artifact(last_run(args.score_on), "scene")
    scene = art.read_scene(scene_dir)
    size = max(scene.test_cameras[0].width, scene.test_cameras[0].height)
    suite = MetricSuite.load(("vgg",))
    doc = {
        "scored_on": f"the test photos of {args.score_on.name} at {size} px ({len(scene.test)} photos)",
        "runs": {},
    }
    for spec in args.run:
        label, folder = spec.split("=", 1)
        folder = Path(folder)
        last = last_run(folder)
        train, _ = load_scene_cameras(step_artifact(last, "scene"))
        factor = size / max(train[0].width, train[0].height)
        pose_diff = _same_poses([c.scaled(factor) for c in train], scene.train_cameras)
        if pose_diff > 1e-6:
            raise SystemExit(
                f"{label}: its cameras are not the scoring run's (max difference {pose_diff:.2e})"
            )
        t0 = time.perf_counter()
        entry = {
            "photo_size": max(train[0].width, train[0].height),
            "wall_s": round(last.get("wall_s") or 0.0, 1),
            "steps_s": {s["name"]: round(s.get("wall_s") or 0.0, 1) for s in last["steps"]},
            "metrics_at_common_size": score(folder, scene, scene.test_cameras, suite),
        }
        entry["score_s"] = round(time.perf_counter() - t0, 1)
        doc["runs"][label] = entry
        print(label, json.dumps(entry))
    args.out.write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
