"""Markdown and HTML views of a run report, with its images (test-view grid: GT / render / error map)
and matplotlib plots (per-step time, per-view metrics). Everything is written into one folder."""

from __future__ import annotations

import html
import shutil
from pathlib import Path
from typing import Any


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


def _assets(report: dict, out_dir: Path) -> dict[str, str]:
    out_dir.mkdir(parents=True, exist_ok=True)
    assets: dict[str, str] = {}
    grid = report.get("images", {}).get("test_grid")
    if grid and Path(grid).is_file():
        shutil.copyfile(grid, out_dir / "test_grid.png")
        assets["grid"] = "test_grid.png"
    if plot_steps(report, out_dir / "steps.png"):
        assets["steps"] = "steps.png"
    if plot_views(report, out_dir / "views.png"):
        assets["views"] = "views.png"
    return assets


def _tables(report: dict) -> tuple[list[str], list[list[str]], list[str], list[list[str]]]:
    step_head = ["step", "status", "wall s", "CPU s", "peak MiB", "device", "version"]
    step_rows = [
        [
            s["name"],
            s["status"] + (f" ({s['reason']})" if s["reason"] else ""),
            _fmt(s["wall_s"], ".2f"),
            _fmt(s["cpu_s"], ".2f"),
            _fmt(s["peak_mem_mb"], ".0f"),
            _fmt(s["device"]),
            _fmt(s["version"]),
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
        f"total wall {t['wall_s']:.1f} s, CPU {t['cpu_s']:.1f} s, peak memory {t['peak_mem_mb']:.0f} MiB; "
        f"device {report['device'] or 'n/a'}",
    ]
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
    if "grid" in assets:
        lines += [
            "## Test views (rows: ground truth, render, error map)",
            "",
            f"![test views]({assets['grid']})",
            "",
        ]
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


def write_html(report: dict, out_dir: Path) -> Path:
    assets = _assets(report, out_dir)
    sh, sr, vh, vr = _tables(report)
    e = html.escape

    def table(head, rows):
        h = "".join(f"<th>{e(c)}</th>" for c in head)
        body = "".join("<tr>" + "".join(f"<td>{e(c)}</td>" for c in row) + "</tr>" for row in rows)
        return f"<table><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>"

    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>Run report: {e(report['scene']['name'])}</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:2px 8px;text-align:right}td:first-child{text-align:left}"
        "img{max-width:100%}</style></head><body>",
        f"<h1>Run report: {e(report['scene']['name'])}</h1><p>Generated {e(report['generated'])}.</p><ul>",
        *[f"<li>{e(x)}</li>" for x in _summary_lines(report)],
        "</ul>",
    ]
    if "grid" in assets:
        parts.append(
            f"<h2>Test views (rows: ground truth, render, error map)</h2><img src='{assets['grid']}'>"
        )
    if vr:
        parts.append("<h2>Metrics per test view</h2>" + table(vh, vr))
        if "views" in assets:
            parts.append(f"<p><img src='{assets['views']}'></p>")
    parts.append("<h2>Steps</h2>" + table(sh, sr))
    if "steps" in assets:
        parts.append(f"<p><img src='{assets['steps']}'></p>")
    parts.append("</body></html>")
    path = out_dir / "report.html"
    path.write_text("\n".join(parts) + "\n", encoding="utf-8")
    return path
