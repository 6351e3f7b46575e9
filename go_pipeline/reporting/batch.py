"""Batch runs: every scene folder under a root, one Ray task per scene, results as a table (CSV + JSON).

Each task calls the cache-aware ``run_pipeline`` (a rerun only runs what changed) and then builds the
scene's run report; a failing scene becomes a row with its error and the others continue. Ray runs
locally by default (``ray.init(num_cpus=<machine>)``) or joins a cluster with ``address``.
"""

from __future__ import annotations

import csv
import io
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from go_core.errors import GoError
from go_core.io.atomic import atomic_write_json, atomic_write_text

METRIC_COLUMNS = ("psnr", "ssim", "lpips_vgg", "lpips_star", "lpips_alex")
# geometry (scenes with a ground-truth mesh): the final mesh's and the visual hull's
GEOMETRY_COLUMNS = ("chamfer_l1", "fscore_1pct", "hull_chamfer_l1", "hull_fscore_1pct")


def geometry_columns(report: dict) -> dict[str, Any]:
    """The batch table's geometry columns of one scene's report (None where it has no geometry)."""
    meshes = (((report.get("metrics") or {}).get("geometry") or {}).get("meshes")) or {}
    final, hull = meshes.get("final") or {}, meshes.get("hull") or {}
    return {
        "chamfer_l1": final.get("chamfer_l1"),
        "fscore_1pct": final.get("fscore_1pct"),
        "hull_chamfer_l1": hull.get("chamfer_l1"),
        "hull_fscore_1pct": hull.get("fscore_1pct"),
    }


def find_scenes(root: str | Path) -> list[Path]:
    """The immediate sub-folders of ``root`` (not hidden, not starting with '_'), sorted by name."""
    root = Path(root)
    if not root.is_dir():
        raise GoError("batch root is not a folder", root)
    scenes = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith((".", "_")))
    if not scenes:
        raise GoError("no scene folders in the batch root", root)
    return scenes


RAY_AUTH_ENV = "RAY_AUTH_MODE"


def import_ray(local: bool = True):
    """The ``ray`` module, or one GoError saying how to install it (Ray is the ``[ray]`` extra).

    ``local``: the batch starts its own Ray. Ray >= 2.5x turns token authentication on for a new local
    cluster and warns about it on every start unless ``RAY_AUTH_MODE`` is set; Ray reads it when imported,
    so it is set (to token: the same protection, without the warning) before the first import."""
    import sys

    from go_core.extras import require_extra

    require_extra("ray", "go-pipeline batch (scenes on Ray)")
    if local and "ray" not in sys.modules:
        os.environ.setdefault(RAY_AUTH_ENV, "token")
    import ray

    return ray


def run_scene(scene: str, options: dict[str, Any]) -> dict[str, Any]:
    """Run one scene and return its result row (never raises: errors become ``status: failed``)."""
    from go_pipeline.reporting.run_report import build_report
    from go_pipeline.runner import run_pipeline

    t0 = time.perf_counter()
    row: dict[str, Any] = {"scene": Path(scene).name, "path": str(scene), "status": "ok", "error": None}
    workdir = options.get("workdir_root")
    wd = str(Path(workdir) / Path(scene).name) if workdir else None
    if options.get("batch_id"):
        row["attempts"] = _count_attempt(scene, wd, str(options["batch_id"]))
    try:
        summary = run_pipeline(
            scene,
            workdir=wd,
            profile=options.get("profile"),
            overrides=options.get("overrides") or {},
            until=options.get("until"),
            seed=int(options.get("seed", 0)),
            pipeline_path=options.get("pipeline_path"),
            device=options.get("device", "auto"),
            in_process=bool(options.get("in_process", False)),
            quiet=True,
            allow_custom_steps=options.get("allow_custom_steps"),
            allow_outside=bool(options.get("allow_outside", False)),
        )
        row["ran"] = summary.ran
        row["cached"] = [s.name for s in summary.steps if s.cached]
        row["report"] = build_report(scene, wd, options.get("pipeline_path"))
    except Exception as exc:  # noqa: BLE001 - one broken scene must not stop the batch
        row["status"] = "failed"
        row["error"] = str(exc) if isinstance(exc, GoError) else f"{type(exc).__name__}: {exc}"
    row["batch_wall_s"] = time.perf_counter() - t0
    return row


def _count_attempt(scene: str, workdir: str | None, batch_id: str) -> int:
    """This task's attempt number for the scene in this batch (Ray retries a task whose node died; the
    retry resumes from the work dir's artifacts and checkpoints)."""
    from go_pipeline import store

    marks = store.workdir_for(scene, workdir) / "runs" / f"batch-{batch_id}.attempts"
    marks.parent.mkdir(parents=True, exist_ok=True)
    with open(marks, "a", encoding="ascii") as f:
        f.write("+")
    return marks.stat().st_size


@dataclass
class BatchResult:
    rows: list[dict[str, Any]]
    wall_s: float
    ray: dict[str, Any] = field(default_factory=dict)

    @property
    def failed(self) -> list[str]:
        return [r["scene"] for r in self.rows if r["status"] != "ok"]


def run_batch(
    root: str | Path,
    *,
    ray_address: str | None = None,
    num_cpus: int | None = None,
    cpus_per_scene: float = 1.0,
    gpus_per_scene: float = 0.0,
    options: dict[str, Any] | None = None,
    scenes: list[Path] | None = None,
    retries: int = 2,
) -> BatchResult:
    """Run every scene under ``root`` as one Ray task each; returns the rows in scene order.

    A task whose worker or node dies is retried up to ``retries`` times (on any node; it resumes from the
    scene's work dir, which every node must see); each row says its ``attempts``."""
    import uuid

    ray = import_ray(local=not ray_address)

    scenes = scenes if scenes is not None else find_scenes(root)
    options = dict(options or {})
    options.setdefault("batch_id", uuid.uuid4().hex[:12])
    t0 = time.perf_counter()
    started_here = not ray.is_initialized()
    if started_here:
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
        if ray_address:
            ray.init(address=ray_address, **kwargs)
        else:
            ray.init(num_cpus=num_cpus or os.cpu_count() or 1, **kwargs)
    try:
        task = ray.remote(run_scene).options(
            num_cpus=cpus_per_scene, num_gpus=gpus_per_scene, max_retries=retries, retry_exceptions=False
        )
        futures = [task.remote(str(s), options) for s in scenes]
        rows = []
        for scene, fut in zip(scenes, futures, strict=True):
            try:
                rows.append(ray.get(fut))
            except Exception as exc:  # noqa: BLE001 - the worker died (OOM, segfault): still a row
                rows.append(
                    {
                        "scene": scene.name,
                        "path": str(scene),
                        "status": "failed",
                        "error": f"ray task failed: {type(exc).__name__}: {exc}".splitlines()[0],
                    }
                )
        resources = ray.cluster_resources()
    finally:
        if started_here:
            ray.shutdown()
    info = {
        "address": ray_address or "local",
        "cluster_cpus": resources.get("CPU"),
        "cluster_gpus": resources.get("GPU", 0.0),
        "cpus_per_scene": cpus_per_scene,
        "gpus_per_scene": gpus_per_scene,
        "retries": retries,
    }
    return BatchResult(rows, time.perf_counter() - t0, info)


def table_rows(result: BatchResult) -> list[dict[str, Any]]:
    """Flat rows: scene, status, error, model, Gaussians, metrics, total and per-step wall seconds."""
    steps: list[str] = []
    for r in result.rows:
        for s in (r.get("report") or {}).get("steps", []):
            if s["name"] not in steps:
                steps.append(s["name"])
    flat = []
    for r in result.rows:
        rep = r.get("report") or {}
        mean = ((rep.get("metrics") or {}).get("mean")) or {}
        res = rep.get("result") or {}
        row = {
            "scene": r["scene"],
            "status": r["status"],
            "error": r.get("error") or "",
            "model": res.get("model") or "",
            "num_gaussians": res.get("num_gaussians"),
            **{k: mean.get(k) for k in METRIC_COLUMNS},
            **geometry_columns(rep),
            "total_wall_s": (rep.get("totals") or {}).get("wall_s"),
            "total_cpu_s": (rep.get("totals") or {}).get("cpu_s"),
            "peak_mem_mb": (rep.get("totals") or {}).get("peak_mem_mb"),
            "batch_wall_s": r.get("batch_wall_s"),
            "steps_ran": len(r["ran"]) if "ran" in r else None,
            "attempts": r.get("attempts"),
        }
        by_step = {s["name"]: s["wall_s"] for s in rep.get("steps", [])}
        row.update({f"wall_s_{s}": by_step.get(s) for s in steps})
        flat.append(row)
    return flat


def aggregate(flat: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean of each metric and time over the scenes that have it."""
    ok = [r for r in flat if r["status"] == "ok"]
    out: dict[str, Any] = {"scenes": len(flat), "ok": len(ok), "failed": len(flat) - len(ok)}
    times = ("batch_wall_s", "total_wall_s", "total_cpu_s", "peak_mem_mb")
    for key in (*METRIC_COLUMNS, *GEOMETRY_COLUMNS, *times):
        vals = [r[key] for r in ok if isinstance(r.get(key), (int, float))]
        out[f"mean_{key}"] = sum(vals) / len(vals) if vals else None
    return out


def write_results(result: BatchResult, out_dir: str | Path) -> dict[str, Path]:
    """``batch_results.csv`` (the flat table), ``batch_results.json`` (table, aggregate, full per-scene
    reports, Ray info) and ``batch_report.md`` into ``out_dir``."""
    out_dir = Path(out_dir)
    flat = table_rows(result)
    agg = aggregate(flat)
    buf = io.StringIO()
    columns = list(flat[0].keys()) if flat else ["scene"]
    for r in flat:
        columns += [k for k in r if k not in columns]
    writer = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    for r in flat:
        writer.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in columns})
    paths = {
        "csv": out_dir / "batch_results.csv",
        "json": out_dir / "batch_results.json",
        "md": out_dir / "batch_report.md",
    }
    atomic_write_text(paths["csv"], buf.getvalue())
    atomic_write_json(
        paths["json"],
        {
            "schema": "go-pipeline/batch-results",
            "version": 1,
            "rows": flat,
            "aggregate": agg,
            "ray": result.ray,
            "wall_s": result.wall_s,
            "scenes": {r["scene"]: r for r in result.rows},
        },
    )
    atomic_write_text(paths["md"], _markdown(flat, agg, result))
    return paths


def _markdown(flat: list[dict[str, Any]], agg: dict[str, Any], result: BatchResult) -> str:
    def f(v, spec=".3f"):
        return "n/a" if v is None or v == "" else (format(v, spec) if isinstance(v, float) else str(v))

    lines = [
        "# Batch report",
        "",
        f"{agg['ok']} of {agg['scenes']} scenes ok, {agg['failed']} failed; {result.wall_s:.1f} s on Ray "
        f"({result.ray.get('address')}, {f(result.ray.get('cluster_cpus'), '.0f')} CPUs).",
        "",
        "*this batch s*: what each scene took in this batch; *artifacts' wall s*: the steps' own times when "
        "their artifacts were made (cached steps included, so it can exceed this batch's time).",
        "",
        "| scene | status | model | Gaussians | PSNR | SSIM | LPIPS* | LPIPS-alex "
        "| Chamfer (hull) | F@1% (hull) | this batch s | steps ran | artifacts' wall s | CPU s | peak MiB |",
        "|" + "---|" * 15,
    ]
    for r in flat:
        status = r["status"] if not r["error"] else f"{r['status']}: {r['error']}".replace("|", "/")
        lines.append(
            f"| {r['scene']} | {status} | {r['model'] or 'n/a'} | {f(r['num_gaussians'])} | "
            f"{f(r['psnr'], '.2f')} | {f(r['ssim'], '.4f')} | {f(r['lpips_star'], '.2f')} | "
            f"{f(r['lpips_alex'], '.4f')} | {f(r['chamfer_l1'], '.4f')} ({f(r['hull_chamfer_l1'], '.4f')}) | "
            f"{f(r['fscore_1pct'], '.3f')} ({f(r['hull_fscore_1pct'], '.3f')}) | "
            f"{f(r['batch_wall_s'], '.1f')} | {f(r['steps_ran'])} | "
            f"{f(r['total_wall_s'], '.1f')} | {f(r['total_cpu_s'], '.1f')} | {f(r['peak_mem_mb'], '.0f')} |"
        )
    lines.append(
        f"| **mean** | | | | {f(agg['mean_psnr'], '.2f')} | {f(agg['mean_ssim'], '.4f')} | "
        f"{f(agg['mean_lpips_star'], '.2f')} | {f(agg['mean_lpips_alex'], '.4f')} | "
        f"{f(agg['mean_chamfer_l1'], '.4f')} ({f(agg['mean_hull_chamfer_l1'], '.4f')}) | "
        f"{f(agg['mean_fscore_1pct'], '.3f')} ({f(agg['mean_hull_fscore_1pct'], '.3f')}) | "
        f"{f(agg['mean_batch_wall_s'], '.1f')} | | "
        f"{f(agg['mean_total_wall_s'], '.1f')} | {f(agg['mean_total_cpu_s'], '.1f')} | "
        f"{f(agg['mean_peak_mem_mb'], '.0f')} |"
    )
    return "\n".join(lines) + "\n"
