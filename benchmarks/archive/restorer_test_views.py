"""The run's compact restorer applied once to the coarse model's renders at the test views (issue 34: does the
restorer itself move a scene's renders towards the truth?).

For each test view: the coarse render on white, and the restorer's one-pass output at strength 1 (what the
repair would distil at a novel view, without the second model's agreement), as tuned by the run's tune step
and as shipped, each scored by PSNR against the test photo on white. Needs a work dir whose tune step tuned
a restorer (status ok), i.e. a run where the folds kept the tuned restorer.

    python benchmarks/archive/restorer_test_views.py --out OUT.json SCENE_DIR:WORK_DIR ...
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch
from _machine import torch_run_context  # benchmarks/ is on sys.path as a script
from go_pipeline.steps.params import RepairParams


def tuned_run(workdir: Path) -> tuple[Path, dict]:
    """The tune step's artifact that tuned a restorer (status ok, a tuned weights file) and its tune.json."""
    for folder in sorted((workdir / "artifacts" / "tune").iterdir()):
        info_path = folder / "tune.json"
        info = json.loads(info_path.read_text()) if info_path.exists() else {}
        if info.get("status") == "ok":
            return folder, info
    raise SystemExit(f"{workdir}: no tune step that tuned a restorer")


def score_views(scene_dir: Path, workdir: Path, resolution: int) -> dict:
    from go_pipeline.steps._repair_models import compact_engine

    from go_core.diffusion.frame import Frame
    from go_core.gaussians import Gaussians
    from go_core.metrics.psnr import psnr
    from go_core.repair.data import bchw_to_hwc, framed_input, hwc_to_bchw, on_white, render_rgb_alpha_depth
    from go_core.scene.loader import load_scene

    folder, info = tuned_run(workdir)
    name = info["compact"]["name"]
    engines = {
        "tuned": compact_engine(name, "cpu", folder / info["tuned"]),
        "shipped": compact_engine(name, "cpu"),
    }
    coarse = Gaussians.load(next((workdir / "artifacts" / "coarse").glob("*/gaussians.npz")))
    rows = []
    for view in load_scene(scene_dir).test:
        rgb, alpha, _ = render_rgb_alpha_depth(coarse, view.camera)
        truth = on_white(torch.from_numpy(view.image), torch.from_numpy(view.mask))
        frame = Frame.choose(view.camera.height, view.camera.width, alpha)
        square = framed_input(frame, resolution, rgb)
        row = {"view": view.name, "coarse": psnr(rgb, truth)}
        for label, engine in engines.items():
            out = engine.repair_one_pass(square, 1.0)
            restored = bchw_to_hwc(frame.from_square(out.float(), hwc_to_bchw(rgb)))[..., :3].clamp(0.0, 1.0)
            row[label] = psnr(restored, truth)
        rows.append(row)
    means = {k: float(np.mean([r[k] for r in rows])) for k in ("coarse", "tuned", "shipped")}
    return {"restorer": name, "tune_dir": str(folder), "mean": means, "views": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", help="SCENE_DIR:WORK_DIR")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument(
        "--resolution",
        type=int,
        default=RepairParams().compact_resolution,
        help="side of the restorer's input (default: repair.compact_resolution's)",
    )
    args = ap.parse_args()
    where = torch_run_context()
    result = {
        "command": f"python benchmarks/archive/restorer_test_views.py {' '.join(sys.argv[1:])} ({where})",
        "runs": {},
    }
    for spec in args.runs:
        scene, work = spec.rsplit(":", 1)
        result["runs"][Path(work).name] = score_views(Path(scene), Path(work), args.resolution)
        print(Path(work).name, result["runs"][Path(work).name]["mean"], flush=True)
    args.out.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
