"""Real-capture benchmark (issue 33): the pipeline on real photos, coarse model and full pipeline.

Captures (``--captures``, default all three):
  real/ethiopian_head, real/blowtorch   the shared scene folders as they are (4 train + 8 test views)
  photos/ethiopian_head                 the 66-photo set with its reference masks and poses: the 4
                                        ``train_views`` for training, the other 62 photos as test views,
                                        built into ``<workroot>/scenes/`` at ``--photo-size`` px on the
                                        long side (benchmarks/archive/photo_scene.py; evaluation data,
                                        never product input)
Stages (``--stages``): ``coarse`` runs the real runner up to the coarse step and scores the coarse model on
the test views with the eval step's metric suite; ``full`` runs the whole pipeline to eval. Both report
PSNR / SSIM / LPIPS* (x100 LPIPS-vgg, on white, paper protocol), every step's wall / CPU seconds (from its
manifest), and the silhouette error of the scored model on the test views: mean |alpha - mask| (%), IoU of
alpha > 0.5 with the mask, and the see-through share (pixels of the mask interior, eroded 2 px, with alpha <
0.5). A run that fails (e.g. a collapsed coarse model) is recorded with its error. Resumable: a (capture,
variant, stage) already in ``--out`` is skipped unless ``--force``.

    python benchmarks/archive/real_captures.py --workroot /tmp/real \
        --out benchmarks/results/real_captures.json --sheets docs/img \
        [--variant NAME:step.param=value,...] [--stages coarse full]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from go_pipeline.store import read_manifest

sys.path.insert(0, str(Path(__file__).resolve().parent))

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
CAPTURES = ("real/ethiopian_head", "real/blowtorch", "photos/ethiopian_head")


def parse_variant(text: str) -> tuple[str, dict]:
    """``name:step.param=value,...`` (values parsed as YAML) → (name, overrides); ``name`` alone: none."""
    import yaml

    name, _, rest = text.partition(":")
    pairs = [p for p in rest.split(",") if p]
    return name, {k: yaml.safe_load(v) for k, v in (p.split("=", 1) for p in pairs)}


def scene_folder(capture: str, data: Path, workroot: Path, photo_size: int) -> Path:
    """The scene folder of a capture (photo sets are built once into the work root)."""
    if capture.startswith("photos/"):
        from photo_scene import build_photo_scene

        name = capture.split("/", 1)[1]
        return build_photo_scene(data / capture, workroot / "scenes" / f"{name}_{photo_size}", photo_size)
    return data / capture


def silhouette_error(alphas: list[np.ndarray], masks: list[np.ndarray], erode: int = 2) -> dict:
    """Alpha vs mask on the test views: mean |alpha - mask| (%), IoU at 0.5, see-through share (%)."""
    import torch

    from go_core.coarse.regularizers import eroded_mask

    l1, iou, holes = [], [], []
    for a, m in zip(alphas, masks, strict=True):
        mb = m > 0.5
        l1.append(float(np.abs(a - m).mean()))
        ab = a > 0.5
        iou.append(float((ab & mb).sum() / max((ab | mb).sum(), 1)))
        interior = eroded_mask(torch.from_numpy(m.astype(np.float32)), erode).numpy() > 0.5
        holes.append(float((a[interior] < 0.5).mean()) if interior.any() else 0.0)
    return {
        "alpha_l1_pct": round(100 * float(np.mean(l1)), 3),
        "silhouette_iou": round(float(np.mean(iou)), 4),
        "see_through_pct": round(100 * float(np.mean(holes)), 3),
    }


def score_model(gaussians, scene, suite) -> tuple[dict, list[np.ndarray]]:
    """Eval-step metrics (mean over the test views), silhouette error of ``gaussians``, and the renders."""
    import torch
    from go_pipeline.steps.eval import evaluate_scene

    from go_core.metrics.evaluate import mean_metrics
    from go_core.render import render_camera

    renders, alphas = [], []
    white = torch.ones(3)
    with torch.no_grad():
        for cam in scene.test_cameras:
            out = render_camera(gaussians, cam, background=white)
            renders.append(out.rgb[0].clamp(0, 1).numpy().astype(np.float32))
            alphas.append(out.alpha[0, ..., 0].numpy())
    mean = mean_metrics(evaluate_scene(scene, renders, suite, masked=False))
    keys = ("psnr", "ssim", "lpips_star", "lpips_alex")
    result = {k: mean.get(k) for k in keys}
    result.update(silhouette_error(alphas, [np.asarray(v.mask) for v in scene.test]))
    return result, renders


def step_times(summary) -> dict:
    """{step: wall / CPU seconds from its manifest} for every step of the run (cached ones included: the
    manifest keeps the run that made them)."""
    out = {}
    for step in summary.steps:
        m = read_manifest(step.artifact_dir) or {}
        out[step.name] = {"wall_s": m.get("wall_s"), "cpu_s": m.get("cpu_s")}
    return out


def run_stage(
    scene_dir: Path,
    workdir: Path,
    overrides: dict,
    stage: str,
    suite,
    profile: str | None = None,
    seed: int = 0,
) -> tuple[dict, list]:
    """One stage of one variant: its metrics, step times and renders (or the error that stopped it)."""
    from go_core import artifacts as art
    from go_pipeline.runner import run_pipeline

    t0 = time.perf_counter()
    until = "coarse" if stage == "coarse" else "eval"
    try:
        summary = run_pipeline(
            scene_dir,
            workdir=workdir,
            profile=profile,
            overrides=overrides,
            until=until,
            quiet=True,
            seed=seed,
        )
    except Exception as exc:  # a failed step (e.g. CollapsedModelError) is a result here, not a crash
        return {"failed": True, "error": f"{type(exc).__name__}: {exc}"[:2000]}, []
    scene = art.read_scene(summary.step("scene").artifact_dir)
    if stage == "coarse":
        model_dir = summary.step("coarse").artifact_dir
        info = json.loads((Path(model_dir) / "coarse.json").read_text())
        extra = {"gaussians": info["gaussians"], "densify": info["densify"]}
    else:
        final = art.final_model(summary.step("coarse").artifact_dir, summary.step("repair").artifact_dir)
        model_dir = final.folder
        metrics = json.loads((Path(summary.step("eval").artifact_dir) / "metrics.json").read_text())
        extra = {"model": metrics["model"], "eval_step_mean": metrics["mean"]}
    metrics, renders = score_model(art.read_gaussians(model_dir), scene, suite)
    result = {
        **metrics,
        **extra,
        "steps": step_times(summary),
        "run_wall_s": round(time.perf_counter() - t0, 1),
        "resolution": [scene.test[0].camera.width, scene.test[0].camera.height],
        "test_views": len(scene.test),
    }
    return result, [(scene, renders)]


def contact_sheet(rows: dict[str, tuple], out: Path, views: int) -> None:
    """Rows: ground truth, then each stage's renders, for ``views`` test views spread over the test set."""
    from PIL import Image

    from go_core.io.images import composite, thumbnail

    scene = next(iter(rows.values()))[0]
    idx = np.unique(np.linspace(0, len(scene.test) - 1, views).round().astype(int))
    lines = [[thumbnail(composite(scene.test[i].image, scene.test[i].mask, 1.0), 200) for i in idx]]
    lines += [[thumbnail(renders[i], 200) for i in idx] for _, renders in rows.values()]
    sheet = np.concatenate([np.concatenate(r, axis=1) for r in lines], axis=0)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(sheet).save(out, format="JPEG", quality=88)


def markdown_table(result: dict) -> str:
    """One row per capture, variant and stage: quality, silhouette error, Gaussians, coarse / total CPU s."""
    head = (
        "| capture | variant | stage | PSNR / SSIM / LPIPS* | alpha L1 % / IoU / see-through % "
        "| coarse CPU s | all steps CPU s |"
    )
    lines = [head, "|" + "---|" * 7]
    for capture, variants in result["captures"].items():
        for name, slot in variants.items():
            for stage in ("coarse", "full"):
                r = slot.get(stage)
                if r is None:
                    continue
                if r.get("failed"):
                    lines.append(f"| {capture} | {name} | {stage} | failed: {r['error'][:90]} | | | |")
                    continue
                steps = r.get("steps", {})
                total = sum(v["cpu_s"] or 0 for v in steps.values())
                coarse = (steps.get("coarse") or {}).get("cpu_s") or 0
                lines.append(
                    f"| {capture} | {name} | {stage} "
                    f"| {r['psnr']:.2f} / {r['ssim']:.3f} / {r['lpips_star']:.2f} "
                    f"| {r['alpha_l1_pct']:.2f} / {r['silhouette_iou']:.3f} / {r['see_through_pct']:.2f} "
                    f"| {coarse:.0f} | {total:.0f} |"
                )
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--captures", nargs="+", default=list(CAPTURES))
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--workroot", type=Path, required=True)
    ap.add_argument(
        "--variant", action="append", default=[], help="NAME:step.param=value,... (default: defaults)"
    )
    ap.add_argument("--stages", nargs="+", default=["coarse", "full"], choices=["coarse", "full"])
    ap.add_argument("--photo-size", type=int, default=400, help="long side of the photo sets' working images")
    ap.add_argument("--profile", default=None, help="pipeline.yaml profile under every variant")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--sheets", type=Path, default=None, help="folder for real_<capture>_<variant>.jpg")
    ap.add_argument("--sheet-views", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0, help="the run's seed; not 0: entries named NAME@seedN")
    ap.add_argument("--force", action="store_true", help="rerun entries already in --out")
    ap.add_argument("--table", action="store_true", help="print --out as a markdown table and exit")
    args = ap.parse_args(argv)
    if args.table:
        print(markdown_table(json.loads(args.out.read_text())))
        return 0

    from _machine import code_version, cpu_name

    from go_core.metrics.evaluate import MetricSuite

    suite = MetricSuite.load(("vgg", "alex"))
    variants = [parse_variant(v) for v in (args.variant or ["defaults"])]
    result = json.loads(args.out.read_text()) if args.out.exists() else {"captures": {}}
    command = "python benchmarks/archive/real_captures.py " + " ".join(sys.argv[1:] if argv is None else argv)
    result.setdefault("commands", []).append(f"{command} (code {code_version()}, {cpu_name()})")
    result.update(
        {
            "command": command,
            "machine": platform.processor() or platform.machine(),
            "threads": os.environ.get("OMP_NUM_THREADS", "unset"),
            "photo_size": args.photo_size,
        }
    )
    for capture in args.captures:
        scene_dir = scene_folder(capture, args.data, args.workroot, args.photo_size)
        entry = result["captures"].setdefault(capture, {})
        for name, overrides in variants:
            name = name if args.seed == 0 else f"{name}@seed{args.seed}"
            slot = entry.setdefault(name, {"overrides": overrides, "seed": args.seed})
            sheet_rows = {}
            workdir = args.workroot / capture.replace("/", "_") / name
            for stage in args.stages:
                if stage in slot and not args.force:
                    continue
                res, rendered = run_stage(
                    scene_dir, workdir, overrides, stage, suite, args.profile, args.seed
                )
                slot[stage] = res
                shown = {k: res.get(k) for k in ("psnr", "ssim", "lpips_star", "see_through_pct", "error")}
                print(capture, name, stage, shown, flush=True)
                if rendered:
                    sheet_rows[stage] = rendered[0]
                args.out.parent.mkdir(parents=True, exist_ok=True)
                args.out.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
            if args.sheets is not None and sheet_rows:
                out = args.sheets / f"real_{capture.replace('/', '_')}_{name}.jpg"
                contact_sheet(sheet_rows, out, args.sheet_views)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
