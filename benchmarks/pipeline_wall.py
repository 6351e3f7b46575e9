"""The whole chain's wall time per scene at default settings, as a user runs it (issue 34's check: at most
15 min wall per dev scene on 2 cores).

Per scene, `go-pipeline run SCENE --workdir WORKROOT/NAME` (``--profile`` to time a profile) from an empty
work dir (skipped when the work dir already holds a finished run, so a later call only collects), then the
run records under ``runs/``: the first run, in which every step ran, gives the wall and CPU seconds of each
step and of the whole run; a later run that reran some steps (after a code change) is listed with the steps
it ran. Run it on an idle machine: the walls are only meaningful when nothing else competes for the cores.

    python benchmarks/pipeline_wall.py --data ../shared/data/dev --scenes basket milk --workroot W \\
        --out benchmarks/results/pipeline_wall_2cores.json
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
from pathlib import Path

from _lib.machine import code_version, cpu_name

from go_pipeline.commands.runs import load_runs
from go_pipeline.store import read_manifest

LIMIT_S = 15 * 60  # issue 34: the whole pipeline per dev scene on 2 cores


def run_records(workdir: Path) -> list[dict]:
    """The work dir's finished run records, oldest first (``go-pipeline runs``' reader)."""
    return [r for r in load_runs(workdir) if r.get("status") == "finished"]


def step_seconds(step: dict) -> dict:
    """Wall and CPU seconds of one step of a run record, from the manifest of the run that made it."""
    m = read_manifest(step["artifact_dir"]) or {}
    return {"wall_s": m.get("wall_s"), "cpu_s": m.get("cpu_s")}


def describe(record: dict, only_ran: bool) -> dict:
    """A run record's total wall, its steps' seconds (those that ran, when ``only_ran``) and their sums."""
    steps = {s["name"]: step_seconds(s) for s in record["steps"] if s.get("status") == "ran" or not only_ran}
    return {
        "started": record["started"],
        "run_wall_s": round(record["wall_s"], 1),
        "steps": steps,
        "steps_cpu_s": round(sum(v["cpu_s"] or 0 for v in steps.values()), 1),
        "overrides": record.get("overrides") or {},
    }


def metrics(workdir: Path) -> dict:
    """Test-view PSNR / LPIPS* and the final mesh's Chamfer ratio to the hull's, from the outputs."""
    m = json.loads((workdir / "outputs" / "metrics.json").read_text(encoding="utf-8"))
    out = {"psnr": round(m["mean"]["psnr"], 4), "lpips_star": round(m["mean"]["lpips_star"], 4)}
    geo = m.get("geometry") or {}
    if geo.get("status") == "ok":
        out["chamfer_ratio_to_hull"] = round(geo["final"]["chamfer_l1"] / geo["hull"]["chamfer_l1"], 4)
    return out


def scene_entry(scene_dir: Path, workdir: Path, profile: str | None) -> dict:
    """Run the scene (with ``profile``) when its work dir has no finished run, then its first and later
    runs."""
    if not run_records(workdir):
        command = ["go-pipeline", "run", str(scene_dir), "--workdir", str(workdir)]
        subprocess.run(command + (["--profile", profile] if profile else []), check=True)
    first, *later = run_records(workdir)
    entry = {
        "first_run": describe(first, only_ran=False),
        "profile": first.get("profile"),
        "metrics": metrics(workdir),
    }
    entry["later_runs"] = [describe(r, only_ran=True) for r in later]
    entry["within_limit"] = entry["first_run"]["run_wall_s"] <= LIMIT_S
    return entry


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, required=True, help="folder holding the scenes")
    ap.add_argument("--scenes", nargs="+", required=True)
    ap.add_argument("--workroot", type=Path, required=True)
    ap.add_argument("--profile", default=None, help="a pipeline.yaml profile (default: the defaults)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--note", default="", help="what the JSON should say besides (e.g. the runs' code)")
    args = ap.parse_args()
    scenes = {name: scene_entry(args.data / name, args.workroot / name, args.profile) for name in args.scenes}
    result = {
        "benchmark": "pipeline_wall",
        "limit_s": LIMIT_S,
        "machine": {"cpu": cpu_name(), "cores": os.cpu_count()},
        "code": code_version(),
        "command": "go-pipeline run SCENE --workdir W/NAME [--profile P] (empty work dir, idle machine)",
        "scenes": scenes,
        **({"note": args.note} if args.note else {}),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    for name, e in scenes.items():
        wall = e["first_run"]["run_wall_s"]
        print(f"{name:14s} {wall:7.1f} s wall  within {LIMIT_S} s: {e['within_limit']}")


if __name__ == "__main__":
    main()
