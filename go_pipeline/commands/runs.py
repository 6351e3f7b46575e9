"""``go-pipeline runs SCENE``: the experiments table of a work dir (like ``dvc exp show``): one row per run
that did something, with the params that differ between the runs, the metrics of its result and its time.

Read from ``WORKDIR/runs/run-*.json`` (written by every run that ran a step, and by every run that stopped
before its end: status interrupted / failed); a run's metrics come from its
eval artifact while that is still cached (``gc`` / ``clean --old`` delete the others: then "gone").
"""

from __future__ import annotations

import argparse
import json
import re
from datetime import datetime
from pathlib import Path
from typing import Any


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("runs", help="table of the runs in a work dir: differing params, metrics, time")
    p.add_argument("scene", help="scene folder")
    p.add_argument("--workdir", metavar="W", help="the work dir (default: SCENE/.go)")
    p.add_argument("--pipeline", metavar="FILE", help="pipeline.yaml (to resolve each run's params)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=main)


def load_runs(workdir: Path) -> list[dict[str, Any]]:
    """Every recorded run, oldest first (the latest run's summary when no history exists yet)."""
    found = sorted((workdir / "runs").glob("run-*.json"))
    if not found and (workdir / "runs" / "last.json").is_file():
        found = [workdir / "runs" / "last.json"]
    runs = []
    for path in found:
        try:
            runs.append(json.loads(path.read_text()))
        except (OSError, ValueError):
            continue
    runs += unrecorded_runs(workdir, {str(r.get("log_path")) for r in runs})
    return sorted(runs, key=lambda r: r.get("started", ""))


LOG_STEP = re.compile(r"^\s+(\w+)\s+(ran|cached|skipped)\s+([0-9a-f]{12})\s")


def unrecorded_runs(workdir: Path, logged: set[str]) -> list[dict[str, Any]]:
    """Runs that left a log but no record: killed (kill -9, a closed terminal) before their end, or the one
    running now. Their steps are read from the log's step lines."""
    from go_pipeline.lock import WorkdirLock

    logs = sorted(p for p in (workdir / "logs").glob("run-*.log") if str(p) not in logged)
    running = WorkdirLock(workdir).holder_info() is not None
    out = []
    for i, log in enumerate(logs):
        stamp = log.stem.removeprefix("run-")
        try:
            started = (
                datetime.strptime(stamp, "%Y%m%dT%H%M%S.%fZ").strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"
            )
            lines = log.read_text(errors="replace").splitlines()
        except (OSError, ValueError):
            continue
        steps = [
            {"name": m[1], "cached": m[2] == "cached", "key": None}
            for m in (LOG_STEP.match(line) for line in lines)
            if m
        ]
        status = "running" if running and i == len(logs) - 1 else "killed"
        out.append({"started": started, "status": status, "steps": steps, "log_path": str(log)})
    return out


def experiments(workdir: Path, pipeline) -> list[dict[str, Any]]:
    """One dict per run: id, started, profile, seed, params (resolved, flattened), ran, wall_s, metrics."""
    from go_pipeline import store

    rows = []
    current_eval = store.read_ref(workdir, "eval")
    for run in load_runs(workdir):
        steps = {s["name"]: s for s in run.get("steps", [])}
        if run.get("status") in ("killed", "running"):  # known from its log only: no params
            params = None
        else:
            params = _run_params(pipeline, run)
        metrics, model = None, None
        if steps.get("eval", {}).get("artifact_dir"):
            path = Path(steps["eval"]["artifact_dir"]) / "metrics.json"
            if path.is_file():
                data = json.loads(path.read_text())
                metrics, model = data.get("mean", {}), data.get("model")
        rows.append(
            {
                "id": run.get("started", "?"),
                "profile": run.get("profile"),
                "seed": run.get("seed"),
                "params": params,
                "ran": [s["name"] for s in run.get("steps", []) if not s.get("cached")],
                "wall_s": run.get("wall_s"),
                "status": run.get("status", "finished"),
                "metrics": metrics,
                "model": model,
                "eval_gone": "eval" in steps and metrics is None,
                "current": "eval" in steps and steps["eval"].get("key") == current_eval,
            }
        )
    return rows


def _run_params(pipeline, run: dict[str, Any]) -> dict[str, Any]:
    """A recorded run's resolved params, flattened ("step.param")."""
    try:
        resolved = pipeline.resolve_params(run.get("profile"), run.get("overrides") or {})
    except Exception:  # noqa: BLE001 - a run made with another pipeline.yaml: show what is known
        return {f"set {k}": v for k, v in (run.get("overrides") or {}).items()}
    return {f"{st}.{k}": v for st, values in resolved.items() for k, v in values.items()}


def differing(rows: list[dict[str, Any]]) -> list[str]:
    """The params whose value is not the same in every run."""
    known = [r for r in rows if r["params"] is not None]  # killed runs: params unknown
    keys = sorted({k for r in known for k in r["params"]})
    return [k for k in keys if len({json.dumps(r["params"].get(k), sort_keys=True) for r in known}) > 1]


def main(args: argparse.Namespace) -> int:
    from go_core.errors import GoError
    from go_pipeline import store
    from go_pipeline.pipeline import load_pipeline

    if not Path(args.scene).is_dir():
        raise GoError("scene folder not found", args.scene)
    workdir = store.workdir_for(args.scene, args.workdir)
    rows = experiments(workdir, load_pipeline(args.pipeline))
    if not rows:
        raise GoError("no runs recorded yet: run `go-pipeline run` on this scene first", workdir)
    diff = differing(rows)
    if args.json:
        print(json.dumps({"differing_params": diff, "runs": rows}, indent=2, sort_keys=True))
        return 0

    def metric(r: dict, key: str, spec: str) -> str:
        if r["metrics"] is None:
            return "gone" if r["eval_gone"] else "-"
        v = r["metrics"].get(key)
        return "n/a" if v is None else format(v, spec)

    head = ["run (started, UTC)", "profile", "seed", *diff, "steps ran", "wall s", "PSNR", "SSIM", "LPIPS*"]
    head.append("status")
    table = [
        [
            ("* " if r["current"] else "  ") + r["id"][:19].replace("T", " "),
            str(r["profile"] or "-"),
            str(r["seed"]),
            *["?" if r["params"] is None else json.dumps(r["params"].get(k)) for k in diff],
            str(len(r["ran"])),
            "-" if r["wall_s"] is None else f"{r['wall_s']:.1f}",
            metric(r, "psnr", ".2f"),
            metric(r, "ssim", ".4f"),
            metric(r, "lpips_star", ".2f"),
            r["status"],
        ]
        for r in rows
    ]
    widths = [max(len(h), *(len(row[i]) for row in table)) for i, h in enumerate(head)]
    print("  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)).rstrip())
    for row in table:
        print("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip())
    print("(* = the run whose results are current; params shown: those that differ between runs)")
    return 0
