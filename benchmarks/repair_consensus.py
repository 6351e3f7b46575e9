"""Repair with a second seed's agreement (issue 33): how much a second model of the scene helps the repair.

Two runs of the pipeline on one scene, seeds 0 and 1 (the real runner, one work dir each, cached steps
reused), give two final models that agree where the four photos decide the shape and differ where they leave
it open. The repair of the seed-0 run is then made again from the same coarse model and tuned restorer, with
every novel view's repair input taken from what both models render (`go_core.repair.consensus`: alpha the
smaller, colour the alpha-weighted mean; `repair_gaussians(consensus=...)`). Scored like the eval step on
white (PSNR / SSIM / LPIPS*, silhouette error) against the seed-0 run's own repair, per test view too.

    python benchmarks/repair_consensus.py --scene ../shared/data/real/blowtorch --name real/blowtorch \\
        --workdir-a W/a --workdir-b W/b --out OUT [--set step.param=value ...]

`--scene` may be a photo set's scene folder built by `real_captures.py` (`photos/NAME`). The second model
costs a second coarse and repair run (the leave-one-out runs and the tuning are the first run's).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from _machine import code_version
from real_captures import score_model

SEED_B = 1


def final_run(scene_dir: Path, workdir: Path, overrides: dict, seed: int):
    """(run summary, final Gaussians) of the pipeline up to the repair step."""
    from go_core import artifacts as art
    from go_pipeline.runner import run_pipeline

    summary = run_pipeline(
        scene_dir, workdir=workdir, overrides=overrides, until="repair", seed=seed, quiet=True
    )
    final = art.final_model(summary.step("coarse").artifact_dir, summary.step("repair").artifact_dir)
    return summary, art.read_gaussians(final.folder)


def repair_with(summary, consensus, seed: int):
    """The repair step's optimisation on the summary's coarse model and tuned restorer, with the params the
    run's repair step resolved (its manifest), and ``consensus``."""
    from go_pipeline.steps._repair_models import repair_model_named
    from go_pipeline.steps.params import RepairParams
    from go_pipeline.steps.repair import _lpips

    from go_core import artifacts as art
    from go_core.config import from_mapping
    from go_core.repair.data import training_views
    from go_core.repair.repair import repair_gaussians

    inputs = {k: Path(summary.step(k).artifact_dir) for k in ("scene", "mask", "coarse", "tune", "repair")}
    manifest = json.loads((inputs["repair"] / "manifest.json").read_text())
    params = from_mapping(RepairParams, manifest["params"])
    tune_info = art.read_json(inputs["tune"], art.TUNE_INFO)
    model = repair_model_named(str(tune_info.get("repair_model", "sd15")))
    diffusion, _, settings = model.load(inputs, tune_info, params, "cpu")
    lpips, _ = _lpips(params.lpips_net, settings.lpips)
    _, views = training_views(inputs["scene"], inputs["mask"], inputs["coarse"])
    coarse = art.read_gaussians(inputs["coarse"])
    result, _, _ = repair_gaussians(
        coarse, views, diffusion, settings, seed, lpips=lpips, consensus=consensus
    )
    return result


def per_view_psnr(renders: list[np.ndarray], scene) -> list[float]:
    """Each test view's PSNR against the eval step's ground truth."""
    import torch
    from go_pipeline.steps.eval import ground_truths

    from go_core.metrics.psnr import psnr

    return [
        round(psnr(torch.from_numpy(render), torch.from_numpy(truth)), 3)
        for render, truth in zip(renders, ground_truths(scene), strict=True)
    ]


def measure(scene_dir: Path, workdir_a: Path, workdir_b: Path, overrides: dict, suite) -> dict:
    from go_core import artifacts as art

    summary_a, model_a = final_run(scene_dir, workdir_a, overrides, 0)
    _, model_b = final_run(scene_dir, workdir_b, overrides, SEED_B)
    start = time.process_time()
    agreed = repair_with(summary_a, model_b, 0)
    cpu = time.process_time() - start
    scene = art.read_scene(summary_a.step("scene").artifact_dir)
    entry = {"consensus_repair_cpu_s": round(cpu, 1)}
    for name, model in (("seed0", model_a), ("seed1", model_b), ("seed0_with_seed1", agreed)):
        metrics, renders = score_model(model, scene, suite)
        entry[name] = {**metrics, "views": per_view_psnr(renders, scene)}
    return entry


def main() -> int:
    import yaml

    from go_core.metrics.evaluate import MetricSuite

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, required=True, help="the scene folder")
    ap.add_argument("--name", required=True, help="the entry's name in --out (e.g. real/blowtorch)")
    ap.add_argument("--workdir-a", type=Path, required=True, help="work dir of the seed-0 run")
    ap.add_argument("--workdir-b", type=Path, required=True, help="work dir of the seed-1 run")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="STEP.PARAM=VALUE for both")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    overrides = {k: yaml.safe_load(v) for k, v in (s.split("=", 1) for s in args.overrides)}
    result = json.loads(args.out.read_text()) if args.out.exists() else {"scenes": {}}
    result.update(benchmark="benchmarks/repair_consensus.py", code=code_version())
    entry = measure(args.scene, args.workdir_a, args.workdir_b, overrides, MetricSuite.load(("vgg", "alex")))
    result["scenes"][args.name] = {"overrides": overrides, **entry}
    args.out.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
    print(args.name, {k: entry[k]["psnr"] for k in ("seed0", "seed1", "seed0_with_seed1")})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
