"""The report's test-view grid: the eval step's test_grid.png cut into its tiles (one column per test view;
rows ground truth, render, error map) and laid out as an HTML/CSS grid for report.html, so that labels,
images and the colour bar each get their own box and never overlap, at any number of test views."""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import numpy as np

ERROR_VMAX = 0.5  # go_core.metrics.evaluate.error_map's default saturation (mean absolute RGB error)
ROW_LABELS = ("ground truth", "render", "|render - GT|")
PER_BAND = 8  # test views per band of the grid; more views wrap to further bands
COLOUR_BAR_LABEL = "mean |RGB error|"

GRID_CSS = (
    ".tv-grid{display:grid;gap:3px 6px;align-items:end;margin:.5em 0}"
    ".tv-corner,.tv-row{grid-column:1}"
    ".tv-row{white-space:nowrap;font-size:.8em;text-align:right;align-self:center}"
    ".tv-name{font-size:.75em;text-align:center;overflow-wrap:anywhere;padding-top:1em;min-width:0}"
    ".tv-img{display:block;width:100%;height:auto;margin:0 auto}"  # small tiles scale up to the column
    ".tv-bar{display:flex;align-items:center;gap:.5em;font-size:.8em;margin:.3em 0 1em}"
    ".tv-ramp{display:block;width:16em;height:.9em;border:1px solid #888}"
)


def grid_columns(n_views: int, grid_views: int) -> list[int]:
    """The test views (indices) in the eval step's test_grid.png: evenly spread, as steps/eval.py picks."""
    if n_views <= 0:
        return []
    return [int(i) for i in np.unique(np.linspace(0, n_views - 1, min(n_views, grid_views)).round())]


def grid_tiles(report: dict) -> tuple[list[dict], list[list[np.ndarray]]] | None:
    """The grid's test views (metrics entries) and, per view, its three tiles (GT, render, error map) cut
    from the eval step's test_grid.png; None when the report has no grid or no metrics."""
    grid_file = report.get("images", {}).get("test_grid")
    metrics = report.get("metrics")
    if not grid_file or not Path(grid_file).is_file() or not metrics or not metrics["views"]:
        return None
    from PIL import Image

    grid = np.asarray(Image.open(grid_file).convert("RGB"))
    eval_params = next((s["params"] for s in report["steps"] if s["name"] == "eval"), {})
    cols = grid_columns(len(metrics["views"]), int(eval_params.get("grid_views", 8)))
    if not cols:
        return None
    cell_w, cell_h = grid.shape[1] // len(cols), grid.shape[0] // 3
    tiles = [
        [grid[r * cell_h : (r + 1) * cell_h, j * cell_w : j * cell_w + cell_w - 2] for r in range(3)]
        for j in range(len(cols))
    ]
    return [metrics["views"][i] for i in cols], tiles


def view_title(view: dict) -> tuple[str, str]:
    """A grid column's two title lines: the view's name and its PSNR."""
    return view["name"], "n/a" if view["psnr"] is None else f"{view['psnr']:.1f} dB"


def _png_uri(tile: np.ndarray) -> str:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(tile).save(buf, format="PNG", optimize=True)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _band_html(views: list[dict], tiles: list[list[np.ndarray]]) -> list[str]:
    """One band of the grid: a row of view titles, then one row per ROW_LABELS (label, then the tiles).
    Each label and tile is a grid item of its own; ``data-box`` (and ``data-view``) mark them for the
    layout test."""
    e = html.escape
    parts = ["<div class='tv-corner'></div>"]
    for view in views:
        name, psnr = view_title(view)
        parts.append(
            f"<div class='tv-name' data-box='text' data-view='{e(name)}'>{e(name)}<br>{e(psnr)}</div>"
        )
    for r, label in enumerate(ROW_LABELS):
        parts.append(f"<div class='tv-row' data-box='text'>{e(label)}</div>")
        for view, cell in zip(views, tiles, strict=True):
            tile = cell[r]
            parts.append(
                f"<img class='tv-img' data-box='box' data-view='{e(view['name'])}' src='{_png_uri(tile)}' "
                f"width='{tile.shape[1]}' "
                f"height='{tile.shape[0]}' alt='{e(view['name'])}: {e(label)}'>"
            )
    return parts


def colour_bar_html(vmax: float = ERROR_VMAX, stops: int = 11) -> str:
    """The error row's colour scale (magma, 0 to ``vmax``) as a CSS gradient with its label, one line below
    the grid (never over a column)."""
    from matplotlib import colormaps

    cmap = colormaps["magma"]
    colours = ",".join(
        "rgb({},{},{})".format(*(round(255 * c) for c in cmap(i / (stops - 1))[:3])) for i in range(stops)
    )
    return (
        "<div class='tv-bar'>"
        f"<span data-box='text'>{html.escape(ROW_LABELS[2])} row, {html.escape(COLOUR_BAR_LABEL)}:</span>"
        "<span data-box='text'>0</span>"
        f"<span class='tv-ramp' data-box='box' style='background:linear-gradient(to right,{colours})'></span>"
        f"<span data-box='text'>{vmax:g} or more</span></div>"
    )


def html_test_grid(report: dict) -> str | None:
    """The labelled test-view grid for report.html (CSS grid, at most PER_BAND views a band, the colour bar
    below), or None when the report has no grid."""
    found = grid_tiles(report)
    if found is None:
        return None
    views, tiles = found
    per_band = min(len(views), PER_BAND)
    parts = [
        f"<div class='tv'><div class='tv-grid' "
        f"style='grid-template-columns:max-content repeat({per_band},minmax(0,1fr))'>"
    ]
    for start in range(0, len(views), per_band):
        parts += _band_html(views[start : start + per_band], tiles[start : start + per_band])
    parts.append("</div>" + colour_bar_html() + "</div>")
    return "".join(parts)
