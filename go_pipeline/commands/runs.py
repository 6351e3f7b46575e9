"""``go-pipeline runs SCENE``: the experiments table of a work dir (like ``dvc exp show``): one row per run
that did something, with the params that differ between the runs, the metrics of its result and its time.

Read from ``WORKDIR/runs/run-*.json`` (written by every run that ran a step); a run's metrics come from its
eval artifact while that is still cached (``gc`` / ``clean --old`` delete the others: then "gone").
"""

from __future__ import annotations

import argparse
import json
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
    return sorted(runs, key=lambda r: r.get("started", ""))


def experiments(workdir: Path, pipeline) -> list[dict[str, Any]]:
    """One dict per run: id, started, profile, seed, params (resolved, flattened), ran, wall_s, metrics."""
    from go_pipeline import store

    rows = []
    current_eval = store.read_ref(workdir, "eval")
    for run in load_runs(workdir):
        steps = {s["name"]: s for s in run.get("steps", [])}
        try:
            resolved = pipeline.resolve_params(run.get("profile"), run.get("overrides") or {})
            params = {f"{st}.{k}": v for st, values in resolved.items() for k, v in values.items()}
        except Exception:  # noqa: BLE001 - a run made with another pipeline.yaml: show what is known
            params = {f"set {k}": v for k, v in (run.get("overrides") or {}).items()}
        metrics, model = None, None
        if "eval" in steps:
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
                "metrics": metrics,
                "model": model,
                "eval_gone": "eval" in steps and metrics is None,
                "current": "eval" in steps and steps["eval"].get("key") == current_eval,
            }
        )
    return rows


def differing(rows: list[dict[str, Any]]) -> list[str]:
    """The params whose value is not the same in every run."""
    keys = sorted({k for r in rows for k in r["params"]})
    return [k for k in keys if len({json.dumps(r["params"].get(k), sort_keys=True) for r in rows}) > 1]


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
    table = [
        [
            ("* " if r["current"] else "  ") + r["id"][:19].replace("T", " "),
            str(r["profile"] or "-"),
            str(r["seed"]),
            *[json.dumps(r["params"].get(k)) for k in diff],
            str(len(r["ran"])),
            "-" if r["wall_s"] is None else f"{r['wall_s']:.1f}",
            metric(r, "psnr", ".2f"),
            metric(r, "ssim", ".4f"),
            metric(r, "lpips_star", ".2f"),
        ]
        for r in rows
    ]
    widths = [max(len(h), *(len(row[i]) for row in table)) for i, h in enumerate(head)]
    print("  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)).rstrip())
    for row in table:
        print("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip())
    print("(* = the run whose results are current; params shown: those that differ between runs)")
    return 0
