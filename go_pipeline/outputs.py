"""Findable results: ``SCENE/.go/outputs/`` (or ``run --output DIR``) holds the current run's results under
stable names, each written atomically (a temp file renamed into place):

```
model.ply        the final model (export step), INRIA layout
model.spz        the same model as Niantic .spz (export.formats; also model.splat, model.compressed.ply)
model.glb        its surface as a textured mesh, glTF 2.0 binary (mesh step)
model_mesh.ply   the full mesh (vertex colours) as PLY, in the scene's world frame (mesh step)
turntable.gif    the turntable (turntable step); turntable.mp4 / camera_path.mp4 when the step made them
contact_sheet.png  a few turntable frames side by side (turntable step)
metrics.json     PSNR / SSIM / LPIPS per test view and mean (eval step)
report.html      the run report, one self-contained file
index.json       which step artifact (key) each file came from
```
A run whose artifacts did not change since the last publication rewrites nothing (a no-op run stays fast).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

from go_core import artifacts as art
from go_core.formats import FILE_NAMES
from go_core.io.atomic import readable
from go_pipeline import store

OUTPUTS_DIR = "outputs"
INDEX = "index.json"
# stable name -> (step, file in the step's artifact); optional ones are published when the step wrote them
COPIED = {
    "model.ply": ("export", art.POINT_CLOUD.file),
    **{FILE_NAMES[f]: ("export", FILE_NAMES[f]) for f in ("spz", "splat", "compressed_ply")},
    "model.glb": ("mesh", art.MESH_GLB.file),
    "model_mesh.ply": ("mesh", art.MESH_PLY.file),
    "turntable.gif": ("turntable", art.TURNTABLE.file),
    "contact_sheet.png": ("turntable", art.CONTACT_SHEET.file),
    "turntable.mp4": ("turntable", "turntable.mp4"),
    "camera_path.mp4": ("turntable", art.CAMERA_PATH_VIDEO.file),
    "metrics.json": ("eval", art.METRICS.file),
}


def outputs_dir(workdir: Path, output: str | Path | None = None) -> Path:
    return Path(output).resolve() if output is not None else Path(workdir) / OUTPUTS_DIR


def _copy_atomic(src: Path, dst: Path) -> None:
    tmp = dst.with_name(f".{dst.name}.tmp-{os.getpid()}")
    shutil.copyfile(src, tmp)
    os.replace(tmp, dst)
    readable(dst)


def _read_index(out: Path) -> dict[str, Any]:
    try:
        return json.loads((out / INDEX).read_text())
    except (OSError, ValueError):
        return {}


def publish(
    scene_dir: Path,
    workdir: Path,
    keys: dict[str, str],
    output: str | Path | None = None,
    pipeline_path: str | Path | None = None,
) -> dict[str, Path]:
    """Copy the current results to the outputs folder under stable names and write the report there.

    ``keys``: step -> key of the artifact this run used (RunSummary). Returns stable name -> path of what
    the folder holds now."""
    out = outputs_dir(workdir, output)
    index = _read_index(out)
    wanted = {
        name: store.artifact_path(workdir, step, keys[step]) / file
        for name, (step, file) in COPIED.items()
        if step in keys and (store.artifact_path(workdir, step, keys[step]) / file).is_file()
    }
    names = [*wanted, "report.html"]
    if index.get("keys") == keys and all((out / n).is_file() for n in names):
        return {n: out / n for n in names}  # nothing changed since the last publication
    out.mkdir(parents=True, exist_ok=True)
    for name, src in wanted.items():
        _copy_atomic(src, out / name)
    for stale in set(COPIED) - set(wanted):  # e.g. a run --until eval leaves no stale model behind
        (out / stale).unlink(missing_ok=True)
    from go_core.io.atomic import atomic_write_json, atomic_write_text
    from go_pipeline.reporting.render import html_report
    from go_pipeline.reporting.run_report import build_report

    report = build_report(scene_dir, workdir, pipeline_path)
    report["outputs"] = {n: str(out / n) for n in names}
    readable(atomic_write_text(out / "report.html", html_report(report)))
    index = {"scene": str(scene_dir), "keys": keys, "files": {n: str(p) for n, p in wanted.items()}}
    readable(atomic_write_json(out / INDEX, index))
    return {n: out / n for n in names}


def published_outputs(workdir: Path, manifests: dict[str, dict]) -> dict[str, str]:
    """The files of ``WORKDIR/outputs`` (stable names) when they were published from these artifacts, so the
    report names ``outputs/model.ply`` rather than a path under artifacts/<step>/<key>/; else empty."""
    out = workdir / OUTPUTS_DIR
    try:
        index = json.loads((out / INDEX).read_text())
    except (OSError, ValueError):
        return {}
    keys = index.get("keys", {})
    if any(manifests.get(step, {}).get("key") != key for step, key in keys.items()):
        return {}
    return {name: str(out / name) for name in sorted(index.get("files", {})) if (out / name).is_file()}


def result_lines(
    summary, files: dict[str, Path], scene_arg: str, profile: str | None, cwd: Path | None = None
) -> list[str]:
    """What the end of a run prints: the model used and its metrics, where the results are, and the next
    command to try."""
    cwd = Path.cwd() if cwd is None else cwd

    def show(p: Path) -> str:
        try:
            return str(p.relative_to(cwd))
        except ValueError:
            return str(p)

    lines: list[str] = []
    metrics = None
    if "metrics.json" in files:
        metrics = json.loads(files["metrics.json"].read_text())
    if metrics is not None:
        mean = metrics.get("mean", {})
        model = metrics.get("model", "?")
        why = metrics.get("model_reason", "")
        lines.append(f"result: the {model} model" + (f" ({_short(why)})" if why else ""))

        def fmt(k: str, spec: str, unit: str = "") -> str:
            v = mean.get(k)
            return "n/a" if v is None else f"{format(v, spec)}{unit}"

        lines.append(
            f"  {len(metrics.get('views', []))} test views: PSNR {fmt('psnr', '.2f', ' dB')}, "
            f"SSIM {fmt('ssim', '.4f')}, LPIPS* {fmt('lpips_star', '.2f')}"
        )
        geo = metrics.get("geometry") or {}
        if geo.get("status") == "ok":
            final, hull = geo["final"], geo["hull"]
            lines.append(
                f"  mesh vs ground truth: Chamfer-L1 {final['chamfer_l1']:.4f} (visual hull "
                f"{hull['chamfer_l1']:.4f}), F@1% {final['fscore_1pct']:.3f} ({hull['fscore_1pct']:.3f})"
            )
    lines += what_you_got(files, show)
    if profile in ("example", "test"):
        nxt = (
            f"go-pipeline run {scene_arg} --profile paper   # the paper's full-length settings "
            f"(about {PAPER_TIME_FACTOR}x this run's time)"
        )
    else:
        nxt = f"go-pipeline runs {scene_arg}   # compare this run with the earlier ones"
    lines.append(f"next: open {show(files['report.html'])} in a browser, or {nxt}")
    return lines


# what each published file is, in the order the end of a run lists them
WHAT = {
    "model.ply": "the model (INRIA 3DGS .ply: SuperSplat, SIBR, most viewers)",
    "model.spz": "the model, ~10x smaller (Niantic .spz)",
    "model.splat": "the model for antimatter15-style web viewers (.splat)",
    "model.compressed.ply": "the model, compressed for SuperSplat",
    "model.glb": "its surface as a textured mesh (glTF 2.0: Blender, game engines, web pages)",
    "model_mesh.ply": "the full mesh with vertex colours as .ply, in the scene's world frame",
    "report.html": "the report: metrics, 3D viewer, images (one self-contained file)",
    "turntable.gif": "turntable",
    "turntable.mp4": "turntable (video)",
    "camera_path.mp4": "video through the training cameras",
    "contact_sheet.png": "contact sheet of the turntable",
    "metrics.json": "PSNR / SSIM / LPIPS per test view",
}
# the paper profile against the example profile, in run time (coarse 10k iterations at full resolution and
# the paper's repair settings: 616-655 CPU s for coarse alone against ~130 CPU s for the whole example run)
PAPER_TIME_FACTOR = 5


def what_you_got(files: dict[str, Path], show) -> list[str]:
    """The "what you got" block: each published file with what it is, in one folder."""
    names = [n for n in WHAT if n in files]
    if not names:
        return []
    folder = files[names[0]].parent
    lines = [f"what you got, in {show(folder)}/:"]
    width = max(len(n) for n in names)
    lines += [f"  {n:<{width}}  {WHAT[n]}" for n in names]
    return lines


def _short(text: str, n: int = 90) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[: n - 3] + "..."
