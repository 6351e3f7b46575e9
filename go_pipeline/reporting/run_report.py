"""The run report of one scene: what ran, how long it took, how good the result is.

Built only from what is on disk (the step manifests of the work dir, the eval artifact's metrics.json,
runs/last.json), so a report can be produced any time after a run, also for a partial run. Keys are stable
and described by ``data_schema/run_report.schema.json``.
"""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from go_core import artifacts as art
from go_core.formats import FILE_NAMES
from go_pipeline import store

REPORT_SCHEMA_ID = "go-pipeline/run-report"
REPORT_VERSION = 1
METRIC_KEYS = ("psnr", "ssim", "lpips_vgg", "lpips_alex", "lpips_star")
GEOMETRY_KEYS = ("chamfer_l1", "fscore_1pct", "fscore_2pct", "normal_consistency", "silhouette_iou")


def schema_path() -> Path:
    """The JSON Schema of the report (packaged data_schema/)."""
    from go_pipeline.resources import schema_path as packaged

    return packaged("run_report")


def validate_report(report: dict) -> None:
    """Raise jsonschema.ValidationError when ``report`` does not follow the schema."""
    import jsonschema

    jsonschema.validate(report, json.loads(schema_path().read_text()))


def code_digest(code: dict[str, str] | None) -> str | None:
    """12 hex digits naming a step's code (its files and their SHA-256, from the manifest), or None."""
    if not code:
        return None
    import hashlib

    return hashlib.sha256(json.dumps(code, sort_keys=True).encode()).hexdigest()[:12]


def _step_order(workdir: Path, manifests: dict[str, dict], pipeline_path: str | Path | None) -> list[str]:
    try:
        from go_pipeline.pipeline import load_pipeline

        order = [s for s in load_pipeline(pipeline_path).order if s in manifests]
        return order + sorted(s for s in manifests if s not in order)
    except Exception:  # noqa: BLE001 - a report of foreign artifacts still lists them, by start time
        return sorted(manifests, key=lambda s: manifests[s].get("started", ""))


def _last_run(workdir: Path) -> dict[str, Any]:
    path = workdir / "runs" / "last.json"
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def _result(manifests: dict[str, dict], metrics: dict | None) -> dict[str, Any]:
    """Which model the result is (repair / coarse) and why."""
    repair = manifests.get("repair")
    repair_record = (repair or {}).get("record", {})
    repair_ran = bool(repair) and repair_record.get("status", "ok") == "ok"
    if metrics is not None:
        model, reason = metrics.get("model"), metrics.get("model_reason", "")
    elif repair_ran:
        model = "repair"
        reason = f"repair ran: {repair_record.get('repair_model', 'sd15')} ({repair_record.get('lora', '')})"
    elif "coarse" in manifests:
        model = "coarse"
        reason = (
            f"repair status {repair_record.get('status')!r}: {repair_record.get('reason', 'no reason given')}"
            if repair
            else "the repair step has not run"
        )
    else:
        model, reason = None, "no model trained yet"
    count = None
    if metrics is not None:
        count = metrics.get("num_gaussians")
    if count is None and model in manifests:
        rec = manifests[model].get("record", {})
        count = rec.get("num_gaussians", rec.get("gaussians"))
    return {
        "model": model,
        "reason": reason,
        "repair_ran": repair_ran,
        "repair_status": repair_record.get("status") if repair else None,
        "num_gaussians": int(count) if isinstance(count, (int, float)) else None,
    }


def build_report(
    scene_dir: str | Path, workdir: str | Path | None = None, pipeline_path: str | Path | None = None
) -> dict[str, Any]:
    """The run report dict of a scene's work dir (see the schema for the keys)."""
    scene_dir = Path(scene_dir)
    wd = store.workdir_for(scene_dir, workdir)
    manifests = store.current_manifests(wd)
    last = _last_run(wd)
    last_status = {s["name"]: s for s in last.get("steps", [])}
    steps = [
        _step_entry(name, manifests[name], last_status.get(name, {}))
        for name in _step_order(wd, manifests, pipeline_path)
    ]
    metrics = None
    metrics_dir = store.artifact_dir(wd, "eval") if "eval" in manifests else None
    if metrics_dir is not None and art.METRICS.path(metrics_dir).is_file():
        metrics = art.read_json(metrics_dir, art.METRICS)
    devices = sorted({s["device"] for s in steps if s["device"]})
    libraries: dict[str, str] = {}
    for name in (s["name"] for s in steps):
        libraries.update(manifests[name].get("libraries", {}))
    images, files = _images_and_files(wd, manifests, metrics_dir)
    return {
        "schema": REPORT_SCHEMA_ID,
        "version": REPORT_VERSION,
        "generated": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "scene": {"name": scene_dir.resolve().name, "path": str(scene_dir)},
        "workdir": str(wd),
        "device": devices[0] if len(devices) == 1 else ("+".join(devices) if devices else None),
        "versions": {"libraries": libraries, "steps": {s["name"]: s["version"] for s in steps}},
        "last_run": {k: last.get(k) for k in ("profile", "seed", "started", "finished", "wall_s")}
        if last
        else None,
        "steps": steps,
        "totals": {
            "wall_s": sum(s["wall_s"] for s in steps),
            "cpu_s": sum(s["cpu_s"] for s in steps),
            "peak_mem_mb": max((s["peak_mem_mb"] for s in steps), default=0.0),
            "rasterizer_build_s": sum(float(s["record"].get("rasterizer_build_s", 0.0)) for s in steps),
        },
        "result": _result(manifests, metrics),
        "metrics": _metrics_block(metrics),
        "images": images,
        "files": files,
        "warnings": mixed_run_problems(manifests),
        "settings": _settings(wd),
    }


def _step_entry(name: str, m: dict, run_info: dict) -> dict[str, Any]:
    """One step's row of the report from its manifest and its entry in the last run (``run_info``)."""
    rec = m.get("record", {})
    return {
        "name": name,
        "version": m.get("version"),
        "code": code_digest(m.get("code")),
        "key": m.get("key"),
        "status": rec.get("status", "ok"),
        "reason": rec.get("reason"),
        "cached_in_last_run": run_info.get("cached") if run_info else None,
        "wall_s": float(m.get("wall_s", 0.0)),
        "cpu_s": float(m.get("cpu_s", 0.0)),
        "peak_mem_mb": float(m.get("peak_mem_mb", 0.0)),
        "device": m.get("device"),
        "params": m.get("params", {}),
        "finished": m.get("finished"),
        "record": rec,
    }


def _images_and_files(wd: Path, manifests: dict, metrics_dir: Path | None) -> tuple[dict, dict]:
    """The report's images (test grid, geometry, turntable, ...) and result files (model, mesh, curves,
    ...), by label, where the steps wrote them."""
    images = {}
    for label, artifact in (("test_grid", art.TEST_GRID), ("geometry", art.GEOMETRY_PICTURE)):
        if metrics_dir is not None and artifact.path(metrics_dir).is_file():
            images[label] = str(artifact.path(metrics_dir))
    files = {}
    for label, step, name in (
        ("turntable", "turntable", art.TURNTABLE.file),
        ("contact_sheet", "turntable", art.CONTACT_SHEET.file),
        ("camera_path", "turntable", art.CAMERA_PATH_VIDEO.file),
        ("curves_coarse", "coarse", art.CURVES.file),
        ("curves_repair", "repair", art.CURVES.file),
        ("model_ply", "export", art.POINT_CLOUD.file),
        ("model_spz", "export", FILE_NAMES["spz"]),
        ("scene_cameras", "scene", art.SCENE_INFO.file),
        ("model_glb", "mesh", art.MESH_GLB.file),
        ("model_mesh", "mesh", art.MESH_PLY.file),
    ):
        found = store.artifact_dir(wd, step) if step in manifests else None
        if found is not None and (found / name).is_file():
            (images if label in ("turntable", "contact_sheet", "camera_path") else files)[label] = str(
                found / name
            )
    return images, files


def _settings(workdir: Path) -> dict[str, Any] | None:
    """The work dir's remembered profile / --set / seed (params.yaml), or None."""
    from go_pipeline.workspace import load_settings

    try:
        saved = load_settings(workdir)
    except Exception:  # noqa: BLE001 - a damaged params.yaml must not hide the report
        return None
    return saved.to_dict() if saved is not None else None


def mixed_run_problems(manifests: dict[str, dict]) -> list[str]:
    """Why these artifacts do not belong to one run: a step's manifest names an upstream artifact (key)
    other than the upstream artifact the report shows, or one that is gone. Empty when consistent."""
    problems = []
    for step, m in manifests.items():
        for _, inp in sorted((m.get("inputs") or {}).items()):
            up = inp.get("step")
            if not up:
                continue
            if up not in manifests:
                problems.append(
                    f"{step} was made from a {up} artifact that is gone ({str(inp.get('key'))[:12]})"
                )
            elif manifests[up].get("key") != inp.get("key"):
                problems.append(
                    f"{step} was made from another {up} artifact ({str(inp.get('key'))[:12]}) than the "
                    f"{up} shown here ({str(manifests[up].get('key'))[:12]})"
                )
    return problems


def _metrics_block(metrics: dict | None) -> dict[str, Any] | None:
    if metrics is None:
        return None
    mean = metrics.get("mean", {})
    return {
        "mean": {k: mean.get(k) for k in METRIC_KEYS},
        "masked_mean": {k: mean["masked"].get(k) for k in METRIC_KEYS} if "masked" in mean else None,
        "views": [
            {"name": v["name"], **{k: v.get(k) for k in METRIC_KEYS}} for v in metrics.get("views", [])
        ],
        "lpips_status": metrics.get("lpips_status", {}),
        "protocol": metrics.get("protocol", {}),
        "geometry": geometry_block(metrics.get("geometry")),
    }


def geometry_block(geometry: dict | None) -> dict[str, Any] | None:
    """metrics.json's ``geometry``, reduced to the report's figures per mesh (final, hull), or why none."""
    if geometry is None:
        return None
    if geometry.get("status") != art.STATUS_OK:
        return {"status": geometry.get("status"), "reason": geometry.get("reason", "")}
    meshes = {k: v for k, v in geometry.items() if isinstance(v, dict) and "chamfer_l1" in v}
    return {
        "status": art.STATUS_OK,
        "meshes": {name: {k: m.get(k) for k in GEOMETRY_KEYS} for name, m in meshes.items()},
        "protocol": geometry.get("protocol", {}),
    }
