"""Markdown and HTML views of a run report, with its images (test-view grid: GT / render / error map)
and matplotlib plots (per-step time, per-view metrics). Everything is written into one folder."""

from __future__ import annotations

import html
import shutil
from pathlib import Path
from typing import Any

from go_pipeline.reporting.grid import (
    COLOUR_BAR_LABEL,
    ERROR_VMAX,
    GRID_CSS,
    PER_BAND,
    ROW_LABELS,
    grid_tiles,
    html_test_grid,
    view_title,
)

GRID_CAPTION = "columns: the test views; rows: ground truth, render, error |render - GT|"
GEOMETRY_CAPTION = (
    "the first test view: ground-truth mesh | the final model's mesh (vertex colours) | "
    "the visual hull's mesh"
)
GEOMETRY_HEAD = ["mesh", "Chamfer-L1", "F@1%", "F@2%", "normal consistency", "silhouette IoU"]


def geometry_rows(report: dict) -> tuple[list[list[str]], str]:
    """Rows of the geometry table (final mesh, hull mesh) and a line saying how they were measured or why
    there are none."""
    g = (report.get("metrics") or {}).get("geometry")
    if not g:
        return [], ""
    if g.get("status") != "ok":
        return [], f"no geometry metrics: {g.get('reason', '')}"
    rows = [
        [name, *(_fmt(m.get(k), ".4f") for k in ("chamfer_l1", "fscore_1pct", "fscore_2pct"))]
        + [_fmt(m.get("normal_consistency"), ".4f"), _fmt(m.get("silhouette_iou"), ".4f")]
        for name, m in g["meshes"].items()
    ]
    p = g.get("protocol", {})
    note = (
        f"against the scene's ground-truth mesh: {p.get('samples_per_surface')} points per surface "
        f"(seed {p.get('seed')}), F-score at {p.get('fscore_thresholds', '')}; "
        "silhouette IoU on the test views"
    )
    return rows, note


def _fmt(v: Any, spec: str = ".3f") -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float):
        return format(v, spec)
    return str(v)


def plot_steps(report: dict, path: Path) -> Path | None:
    """Horizontal bars of wall and CPU seconds per step."""
    steps = report["steps"]
    if not steps:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [s["name"] for s in steps]
    y = range(len(steps))
    fig, ax = plt.subplots(figsize=(6, 0.4 * len(steps) + 1.2), dpi=100)
    ax.barh([i - 0.2 for i in y], [s["wall_s"] for s in steps], height=0.4, label="wall s")
    ax.barh([i + 0.2 for i in y], [s["cpu_s"] for s in steps], height=0.4, label="CPU s")
    ax.set_yticks(list(y), names)
    ax.invert_yaxis()
    ax.set_xlabel("seconds")
    ax.legend(loc="lower right")
    ax.set_title("time per step")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_views(report: dict, path: Path) -> Path | None:
    """Per-view PSNR and LPIPS (vgg when available, else alex)."""
    metrics = report.get("metrics")
    if not metrics or not metrics["views"]:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    views = metrics["views"]
    names = [v["name"] for v in views]
    x = range(len(views))
    fig, ax = plt.subplots(figsize=(max(6, 0.35 * len(views) + 2), 3.2), dpi=100)
    ax.bar(list(x), [v["psnr"] or 0.0 for v in views], color="tab:blue")
    ax.set_ylabel("PSNR (dB)", color="tab:blue")
    ax.set_xticks(list(x), names, rotation=60, ha="right", fontsize=7)
    lp_key = "lpips_vgg" if any(v["lpips_vgg"] is not None for v in views) else "lpips_alex"
    if any(v[lp_key] is not None for v in views):
        ax2 = ax.twinx()
        ax2.plot(list(x), [v[lp_key] for v in views], "o-", color="tab:red")
        ax2.set_ylabel(lp_key.replace("_", "-").upper(), color="tab:red")
    ax.set_title("test views")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_test_grid(report: dict, path: Path) -> Path | None:
    """The eval step's test grid redrawn for report.md with its columns named (view, PSNR), its rows named
    and a colour bar for the error row (magma, 0 to ERROR_VMAX mean absolute RGB error) below the grid.
    Constrained layout gives every title, label and the bar their own space (no overlap)."""
    found = grid_tiles(report)
    if found is None:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    views, tiles = found
    per_row = min(len(views), PER_BAND)
    bands = -(-len(views) // per_row)
    fig, axes = plt.subplots(
        3 * bands,
        per_row,
        figsize=(1.6 * per_row + 1.2, 1.7 * 3 * bands + 0.8),
        dpi=100,
        squeeze=False,
        layout="constrained",
    )
    for ax in axes.flat:
        ax.axis("off")
    for j, (view, cell) in enumerate(zip(views, tiles, strict=True)):
        band, c = divmod(j, per_row)
        for r in range(3):
            ax = axes[3 * band + r, c]
            ax.imshow(cell[r])
            if r == 0:
                ax.set_title("\n".join(view_title(view)), fontsize=8)
            if c == 0:
                ax.axis("on")
                ax.set_xticks([])
                ax.set_yticks([])
                for spine in ax.spines.values():
                    spine.set_visible(False)
                ax.set_ylabel(ROW_LABELS[r], fontsize=8)
    bar = fig.colorbar(
        ScalarMappable(Normalize(0.0, ERROR_VMAX), colormaps["magma"]),
        ax=axes[-1, :].tolist(),
        location="bottom",
        shrink=0.5,
        aspect=40,
    )
    bar.set_label(f"{ROW_LABELS[2]} row: {COLOUR_BAR_LABEL}", fontsize=8)
    bar.ax.tick_params(labelsize=7)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_curves(report: dict, path: Path) -> Path | None:
    """Training curves (coarse, repair): loss, PSNR on the training views and Gaussian count over
    iterations, from the steps' curves.csv."""
    import csv

    found = {
        step: report.get("files", {}).get(f"curves_{step}")
        for step in ("coarse", "repair")
        if report.get("files", {}).get(f"curves_{step}")
    }
    if not found:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = ("loss", "train_psnr", "gaussians")
    labels = {"loss": "loss", "train_psnr": "PSNR on training views (dB)", "gaussians": "Gaussians"}
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.2), dpi=100)
    for step, csv_path in found.items():
        with open(csv_path, newline="") as f:
            rows = list(csv.DictReader(f))
        if not rows:
            continue
        its = [int(r["iteration"]) for r in rows]
        for ax, key in zip(axes, series, strict=True):
            vals = [float(r[key]) if r.get(key) not in (None, "") else float("nan") for r in rows]
            ax.plot(its, vals, label=step)
    for ax, key in zip(axes, series, strict=True):
        ax.set_xlabel("iteration")
        ax.set_title(labels[key], fontsize=9)
        ax.grid(alpha=0.3)
    axes[0].set_yscale("log")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def _assets(report: dict, out_dir: Path, grid_png: bool = True) -> dict[str, str]:
    """The report's pictures written into ``out_dir``, by label; ``grid_png``: also the labelled test grid
    as a picture (report.md; report.html lays its grid out in HTML)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    assets: dict[str, str] = {}
    if grid_png and plot_test_grid(report, out_dir / "test_grid.png"):
        assets["grid"] = "test_grid.png"
    for key, name in (
        ("turntable", "turntable.gif"),
        ("contact_sheet", "contact_sheet.png"),
        ("camera_path", "camera_path.mp4"),
        ("geometry", "geometry.png"),
    ):
        found = report.get("images", {}).get(key)
        if found and Path(found).is_file():
            shutil.copyfile(found, out_dir / name)
            assets[key] = name
    if plot_curves(report, out_dir / "curves.png"):
        assets["curves"] = "curves.png"
    if plot_steps(report, out_dir / "steps.png"):
        assets["steps"] = "steps.png"
    if plot_views(report, out_dir / "views.png"):
        assets["views"] = "views.png"
    return assets


def _tables(report: dict) -> tuple[list[str], list[list[str]], list[str], list[list[str]]]:
    step_head = ["step", "status", "wall s", "CPU s", "peak MiB", "device", "version / code"]
    step_rows = [
        [
            s["name"],
            s["status"] + (f": {s['reason']}" if s["reason"] else ""),
            _fmt(s["wall_s"], ".2f"),
            _fmt(s["cpu_s"], ".2f"),
            _fmt(s["peak_mem_mb"], ".0f"),
            _fmt(s["device"]),
            s["version"] or (f"code {s['code']}" if s.get("code") else "n/a"),
        ]
        for s in report["steps"]
    ]
    view_head = ["view", "PSNR", "SSIM", "LPIPS-vgg", "LPIPS*", "LPIPS-alex"]
    view_rows = []
    m = report.get("metrics")
    if m:
        for v in m["views"]:
            view_rows.append(
                [
                    v["name"],
                    _fmt(v["psnr"], ".2f"),
                    _fmt(v["ssim"], ".4f"),
                    _fmt(v["lpips_vgg"], ".4f"),
                    _fmt(v["lpips_star"], ".2f"),
                    _fmt(v["lpips_alex"], ".4f"),
                ]
            )
    return step_head, step_rows, view_head, view_rows


def _summary_lines(report: dict) -> list[str]:
    r, t = report["result"], report["totals"]
    lines = [
        f"result: {r['model'] or 'none'} model ({r['reason']}); Gaussians: {_fmt(r['num_gaussians'])}",
        f"total wall {t['wall_s']:.1f} s, CPU {t['cpu_s']:.1f} s (the steps' own times), peak memory "
        f"{t['peak_mem_mb']:.0f} MiB; device {report['device'] or 'n/a'}",
    ]
    if t.get("rasterizer_build_s", 0.0) >= 0.5:
        lines.append(
            "the run that made these steps also compiled the CPU rasterizer once "
            f"({t['rasterizer_build_s']:.0f} s, cached per machine): the CLI's run total includes it, "
            "the step times do not"
        )
    m = report.get("metrics")
    if m:
        mean = m["mean"]
        lines.append(
            f"mean over {len(m['views'])} test views: PSNR {_fmt(mean['psnr'], '.2f')} dB, "
            f"SSIM {_fmt(mean['ssim'], '.4f')}, LPIPS* {_fmt(mean['lpips_star'], '.2f')} (vgg), "
            f"LPIPS-alex {_fmt(mean['lpips_alex'], '.4f')}"
        )
        for net, status in m["lpips_status"].items():
            if status != "ok":
                lines.append(f"LPIPS-{net} {status}")
    else:
        lines.append("no evaluation yet (the eval step has not run)")
    ply = report.get("outputs", {}).get("model.ply") or report.get("files", {}).get("model_ply")
    if ply:
        lines.append(f"model (.ply): {ply}")
    settings = report.get("settings")
    if settings:
        sets = ", ".join(f"{k}={v}" for k, v in settings.get("set", {}).items()) or "none"
        profile = settings.get("profile") or "(none)"
        lines.append(f"settings: profile {profile}, seed {settings.get('seed')}, --set {sets}")
    libs = report["versions"]["libraries"]
    if libs:
        lines.append("versions: " + ", ".join(f"{k} {v}" for k, v in sorted(libs.items())))
    return lines


def write_markdown(report: dict, out_dir: Path) -> Path:
    assets = _assets(report, out_dir)
    sh, sr, vh, vr = _tables(report)

    def table(head, rows):
        out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        out += ["| " + " | ".join(c.replace("|", "/") for c in row) + " |" for row in rows]
        return out

    lines = [f"# Run report: {report['scene']['name']}", "", f"Generated {report['generated']}.", ""]
    lines += [f"- {x}" for x in _summary_lines(report)] + [""]
    lines += [f"> **WARNING:** {w}" for w in report.get("warnings", [])] + [""] * bool(report.get("warnings"))
    if "grid" in assets:
        lines += ["## Test views", "", GRID_CAPTION, "", f"![test views]({assets['grid']})", ""]
    if "turntable" in assets:
        lines += ["## Turntable", "", f"![turntable]({assets['turntable']})", ""]
    if "contact_sheet" in assets:
        lines += ["## Contact sheet", "", f"![contact sheet]({assets['contact_sheet']})", ""]
    if "camera_path" in assets:
        lines += [f"Video along the camera path: [{assets['camera_path']}]({assets['camera_path']})", ""]
    geo_rows, geo_note = geometry_rows(report)
    if geo_rows or geo_note:
        lines += ["## Geometry", "", geo_note, ""] + (
            table(GEOMETRY_HEAD, geo_rows) + [""] if geo_rows else []
        )
    if "geometry" in assets:
        lines += [GEOMETRY_CAPTION, "", f"![meshes]({assets['geometry']})", ""]
    if "curves" in assets:
        lines += ["## Training curves", "", f"![training curves]({assets['curves']})", ""]
    if vr:
        lines += ["## Metrics per test view", ""] + table(vh, vr) + [""]
        if "views" in assets:
            lines += [f"![per-view metrics]({assets['views']})", ""]
    lines += ["## Steps", ""] + table(sh, sr) + [""]
    if "steps" in assets:
        lines += [f"![time per step]({assets['steps']})", ""]
    path = out_dir / "report.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _data_uri(path: Path) -> str:
    import base64

    kinds = {".png": "image/png", ".gif": "image/gif", ".jpg": "image/jpeg", ".mp4": "video/mp4"}
    kind = kinds.get(path.suffix, "image/png")
    return f"data:{kind};base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _viewer_block(report: dict) -> str | None:
    """The interactive viewer of the exported model with the scene's cameras, when both are on disk (and
    of the mesh, when the mesh step wrote one)."""
    files = report.get("files", {})
    if not files.get("model_ply") or not files.get("scene_cameras"):
        return None
    from go_pipeline.reporting.viewer import viewer_data, viewer_html

    turntable = next((s["params"] for s in report["steps"] if s["name"] == "turntable"), {})
    background = turntable.get("background", (1.0, 1.0, 1.0))
    mesh = Path(files["model_mesh"]) if files.get("model_mesh") else None
    data = viewer_data(Path(files["model_ply"]), Path(files["scene_cameras"]).parent, background, mesh)
    return viewer_html(data)


def html_report(report: dict) -> str:
    """The report as one self-contained HTML page (images embedded), for outputs/report.html."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="go-report-") as tmp:
        assets = _assets(report, Path(tmp), grid_png=False)
        uris = {k: _data_uri(Path(tmp) / v) for k, v in assets.items()}
    sh, sr, vh, vr = _tables(report)
    e = html.escape

    def table(head, rows, css=""):
        h = "".join(f"<th>{e(c)}</th>" for c in head)
        body = "".join("<tr>" + "".join(f"<td>{e(c)}</td>" for c in row) + "</tr>" for row in rows)
        return f"<table class='{css}'><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>"

    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>Run report: {e(report['scene']['name'])}</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:2px 8px;text-align:right}td:first-child{text-align:left}"
        "img{max-width:100%}.steps td:nth-child(2){text-align:left}"
        ".warn{background:#fdd;border:2px solid #c00;padding:.5em 1em}" + GRID_CSS + "</style>"
        "</head><body>",
        f"<h1>Run report: {e(report['scene']['name'])}</h1><p>Generated {e(report['generated'])}.</p>",
        *[f"<p class='warn'>{e(w)}</p>" for w in report.get("warnings", [])],
        "<ul>",
        *[f"<li>{e(x)}</li>" for x in _summary_lines(report)],
        "</ul>",
    ]
    grid = html_test_grid(report)
    if grid:
        parts.append(f"<h2>Test views</h2><p>{e(GRID_CAPTION)}</p>{grid}")
    viewer = _viewer_block(report)
    if viewer:
        parts.append("<h2>3D viewer</h2>" + viewer)
    if "turntable" in uris or "camera_path" in uris:
        parts.append("<h2>Turntable and camera path</h2><p>")
        if "turntable" in uris:
            parts.append(f"<img src='{uris['turntable']}' alt='turntable'> ")
        if "camera_path" in uris:
            parts.append(
                f"<video src='{uris['camera_path']}' controls loop muted autoplay playsinline></video>"
            )
        parts.append("</p>")
    geo_rows, geo_note = geometry_rows(report)
    if geo_rows or geo_note:
        parts.append(
            f"<h2>Geometry</h2><p>{e(geo_note)}</p>" + (table(GEOMETRY_HEAD, geo_rows) if geo_rows else "")
        )
    if "geometry" in uris:
        parts.append(f"<p>{e(GEOMETRY_CAPTION)}</p><img src='{uris['geometry']}' alt='meshes'>")
    if "contact_sheet" in uris:
        parts.append(f"<h2>Contact sheet</h2><img src='{uris['contact_sheet']}' alt='contact sheet'>")
    if "curves" in uris:
        parts.append(f"<h2>Training curves</h2><img src='{uris['curves']}'>")
    if vr:
        parts.append("<h2>Metrics per test view</h2>" + table(vh, vr))
        if "views" in uris:
            parts.append(f"<p><img src='{uris['views']}'></p>")
    parts.append("<h2>Steps</h2>" + table(sh, sr, "steps"))
    if "steps" in uris:
        parts.append(f"<p><img src='{uris['steps']}'></p>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def write_html(report: dict, out_dir: Path) -> Path:
    """``out_dir/report.html``, self-contained."""
    from go_core.io.atomic import atomic_write_text

    out_dir.mkdir(parents=True, exist_ok=True)
    return atomic_write_text(out_dir / "report.html", html_report(report))
