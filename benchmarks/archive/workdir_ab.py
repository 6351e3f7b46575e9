"""A/B of pipeline runs already made: per scene, two work dirs (or two runs of one) that differ in a setting,
read back from what the runner recorded. For each side: the run's overrides and seed, the eval step's test
metrics (PSNR, SSIM, LPIPS*, Gaussians; the final mesh's and the visual hull's geometry when the scene has a
ground truth) and the wall seconds of the steps the run computed; then B minus A per scene and the mean over
scenes.

    python benchmarks/archive/workdir_ab.py --label A=control --label B=variant \\
        --pair plate W/plate_C/plate W/plate_V/plate --pair basket W/b_C/basket#RUN_ID W/b_V/basket \\
        --note "..." --out benchmarks/results/NAME.json

A side is ``WORKDIR`` (its latest run) or ``WORKDIR#RUN_ID`` (the id ``go-pipeline runs`` lists, e.g.
``2026-12-05T22:05:48.375Z``); runs are read by that command's own ``load_runs``. ``--merge`` adds the
pairs to an existing --out (same labels)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from _machine import code_version, cpu_name

from go_pipeline.commands.runs import load_runs

METRICS = ("psnr", "ssim", "lpips_star")
GEOMETRY = ("chamfer_l1", "fscore_1pct", "silhouette_iou")


def run_record(side: str) -> tuple[Path, dict]:
    """The work dir and the run a side names (its latest run without an id)."""
    workdir, _, run_id = side.partition("#")
    runs = load_runs(Path(workdir))
    chosen = [r for r in runs if r.get("started") == run_id] if run_id else runs[-1:]
    if not chosen:
        ids = ", ".join(str(r.get("started")) for r in runs) or "none"
        sys.exit(f"workdir_ab: {workdir}: no run {run_id or ''} (runs: {ids})")
    return Path(workdir), chosen[0]


def side_summary(side: str) -> dict:
    """What one run recorded: overrides, seed, test metrics, geometry and the walls of the steps it ran."""
    workdir, run = run_record(side)
    steps = {s["name"]: s for s in run["steps"]}
    ev = steps.get("eval")
    if ev is None or "artifact_dir" not in ev:
        sys.exit(f"workdir_ab: {workdir}: the run has no eval step")
    metrics = json.loads((Path(ev["artifact_dir"]) / "metrics.json").read_text())
    geometry = metrics.get("geometry") or {}
    final, hull = geometry.get("final") or {}, geometry.get("hull") or {}
    return {
        "workdir": str(workdir),
        "run": run.get("started"),
        "seed": run.get("seed"),
        "overrides": run.get("overrides", {}),
        **{k: metrics["mean"][k] for k in METRICS},
        "gaussians": metrics.get("num_gaussians"),
        "model": metrics.get("repair_model") or metrics.get("model"),
        "geometry": {k: final[k] for k in GEOMETRY if k in final},
        "hull_geometry": {k: hull[k] for k in GEOMETRY if k in hull},
        "step_wall_s": {
            name: round(s["wall_s"], 1) for name, s in steps.items() if not s.get("cached") and "wall_s" in s
        },
        "eval_dir": ev["artifact_dir"],
    }


def delta(a: dict, b: dict) -> dict:
    """B minus A on every metric and geometry figure both have."""
    out = {k: b[k] - a[k] for k in METRICS}
    for k in GEOMETRY:
        if k in a["geometry"] and k in b["geometry"]:
            out[k] = b["geometry"][k] - a["geometry"][k]
    return out


def means(scenes: dict) -> dict:
    """Mean of each side's metrics and of the deltas over the scenes."""
    n = len(scenes)
    out = {}
    for part in ("A", "B", "delta"):
        out[part] = {k: sum(s[part][k] for s in scenes.values()) / n for k in METRICS}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pair", action="append", nargs=3, required=True, metavar=("SCENE", "SIDE_A", "SIDE_B"))
    ap.add_argument("--label", action="append", default=[], help="A=NAME or B=NAME (what each side is)")
    ap.add_argument("--note", default="")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--merge", action="store_true")
    args = ap.parse_args()
    labels = dict(item.split("=", 1) for item in args.label)
    doc = (
        json.loads(args.out.read_text())
        if args.merge and args.out.is_file()
        else {"scenes": {}, "commands": []}
    )
    if args.merge and doc.get("labels", labels) != labels:
        sys.exit(f"workdir_ab: {args.out} has labels {doc.get('labels')}, not {labels}")
    for scene, side_a, side_b in args.pair:
        a, b = side_summary(side_a), side_summary(side_b)
        doc["scenes"][scene] = {"A": a, "B": b, "delta": delta(a, b)}
    doc["labels"] = labels
    doc["means"] = means(doc["scenes"])
    if args.note:
        doc["note"] = args.note
    doc["commands"].append(
        f"python benchmarks/archive/workdir_ab.py {' '.join(sys.argv[1:])} "
        f"(code {code_version()}, {cpu_name()})"
    )
    args.out.write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")
    for scene, s in doc["scenes"].items():
        d = s["delta"]
        print(
            f"{scene:16s} A {s['A']['psnr']:.2f} / {s['A']['lpips_star']:.2f}  B {s['B']['psnr']:.2f} / "
            f"{s['B']['lpips_star']:.2f}  delta {d['psnr']:+.2f} dB / LPIPS* {d['lpips_star']:+.2f}"
        )
    m = doc["means"]["delta"]
    print(f"mean delta over {len(doc['scenes'])} scenes: {m['psnr']:+.3f} dB / LPIPS* {m['lpips_star']:+.3f}")


if __name__ == "__main__":
    main()
