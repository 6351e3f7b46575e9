"""Helpers for the report-layout test (no tests here): a synthetic run report with N fake test views (no
pipeline run), headless Chromium (Debian's `chromium`) to lay report.html out, and the overlap check on the
boxes it measures. Run as a script, it saves the screenshots of docs/img/report_grid_{8,20,60}.png:

    python tests/_report_layout.py docs/img
"""

from __future__ import annotations

import html
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from _browser import CHROMIUM_FLAGS as BROWSER_FLAGS
from _browser import find_chromium

CHROMIUM_FLAGS = [*BROWSER_FLAGS, "--force-device-scale-factor=1"]
WIDTH = 1200  # px, the window of tests/test_report_screenshot.py

# Measures every [data-box] element of the test-view grid, once the page is laid out: the box of an image
# or the colour ramp, the box of the glyphs for a text (a Range over its contents: text that spills out of
# its element is caught too). Page coordinates, CSS px; the result goes into <pre id='go-boxes'>.
MEASURE_JS = """
<script>
(() => {
  const boxes = [...document.querySelectorAll('.tv [data-box]')].map(el => {
    let r = el.getBoundingClientRect();
    if (el.dataset.box === 'text') {
      const range = document.createRange();
      range.selectNodeContents(el);
      r = range.getBoundingClientRect();
    }
    return {tag: el.tagName, cls: el.className, text: (el.alt || el.textContent).slice(0, 40),
            view: el.dataset.view || null,
            x: r.left + scrollX, y: r.top + scrollY, w: r.width, h: r.height};
  });
  const pre = document.createElement('pre');
  pre.id = 'go-boxes';
  pre.textContent = JSON.stringify({boxes, viewport: document.documentElement.clientWidth});
  document.body.appendChild(pre);
})();
</script>
"""


def fake_tiles(i: int, size: int) -> list[np.ndarray]:
    """A fake test view's three tiles: a coloured disc on white (ground truth), the disc shifted (render)
    and their error map (magma), each ``size`` px square."""
    from go_core.metrics.evaluate import error_map

    yy, xx = np.mgrid[0:size, 0:size] / size
    colour = np.array([0.2 + 0.6 * ((i * 0.37) % 1), 0.3, 0.8 - 0.5 * ((i * 0.53) % 1)])

    def disc(cx: float) -> np.ndarray:
        inside = ((xx - cx) ** 2 + (yy - 0.5) ** 2 < 0.09)[..., None]
        return np.where(inside, colour, 1.0).astype(np.float32)

    gt, render = disc(0.5), disc(0.5 + 0.02 * (i % 5))
    return [(np.asarray(t) * 255).round().astype(np.uint8) for t in (gt, render)] + [error_map(render, gt)]


def fake_grid(n_views: int, size: int) -> np.ndarray:
    """An eval-step test_grid.png of ``n_views`` columns (GT / render / error rows, 2 px white gap right
    of each column), as steps/eval.py lays it out."""
    cols = [np.concatenate(fake_tiles(i, size), axis=0) for i in range(n_views)]
    cols = [np.pad(c, ((0, 0), (0, 2), (0, 0)), constant_values=255) for c in cols]
    return np.concatenate(cols, axis=1)


def synthetic_report(folder: Path, n_views: int, size: int = 128) -> dict:
    """A run report (data_schema/run_report.schema.json) of a scene with ``n_views`` fake test views, its
    test grid written into ``folder``: what html_report needs, without running the pipeline."""
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    grid = folder / "test_grid.png"
    Image.fromarray(fake_grid(n_views, size)).save(grid)
    views = [
        {"name": f"test_view_{i:03d}", "psnr": 20 + (i * 7) % 9 + 0.25, "ssim": 0.9, "lpips_vgg": 0.1}
        | {"lpips_alex": 0.05, "lpips_star": 10.0}
        for i in range(n_views)
    ]
    mean = {k: float(np.mean([v[k] for v in views])) for k in views[0] if k != "name"}
    step = {"name": "eval", "version": "1", "code": None, "key": "k", "status": "ok", "reason": None}
    step |= {"cached_in_last_run": False, "wall_s": 1.0, "cpu_s": 1.0, "peak_mem_mb": 100.0}
    step |= {"device": "cpu", "params": {"grid_views": 100}, "finished": None, "record": {}}
    return {
        "schema": "go-pipeline/run-report",
        "version": 1,
        "generated": "2000-01-01T00:00:00Z",
        "scene": {"name": f"synthetic_{n_views}", "path": str(folder)},
        "workdir": str(folder),
        "device": "cpu",
        "versions": {"libraries": {}, "steps": {"eval": "1"}},
        "last_run": None,
        "steps": [step],
        "totals": {"wall_s": 1.0, "cpu_s": 1.0, "peak_mem_mb": 100.0},
        "result": {"model": "coarse", "reason": "synthetic", "repair_ran": False}
        | {"repair_status": None, "num_gaussians": 1000},
        "metrics": {"mean": mean, "masked_mean": None, "views": views}
        | {"lpips_status": {"vgg": "ok", "alex": "ok"}, "protocol": {}, "geometry": None},
        "images": {"test_grid": str(grid)},
        "files": {},
        "warnings": [],
        "settings": None,
    }


def chromium(args: list[str], timeout: float = 120.0) -> str:
    """Run headless Chromium with a fresh profile and ``args``; its stdout."""
    browser = find_chromium()
    if browser is None:
        raise RuntimeError("chromium not found (Debian: apt-get install chromium)")
    with tempfile.TemporaryDirectory(prefix="go-chromium-") as profile:
        cmd = [browser, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", *args]
        done = subprocess.run(cmd, check=True, capture_output=True, text=True, timeout=timeout)
    return done.stdout


def layout_boxes(page: Path, width: int = WIDTH) -> dict:
    """The test-view grid's boxes as Chromium lays ``page`` out in a ``width`` px window: a copy of the
    page with MEASURE_JS appended is loaded and its DOM dumped."""
    probe = page.with_name(page.stem + "_probe.html")
    probe.write_text(page.read_text().replace("</body>", MEASURE_JS + "</body>"))
    dom = chromium([f"--window-size={width},2000", "--dump-dom", probe.resolve().as_uri()])
    found = re.search(r"<pre id=\"go-boxes\">(.*?)</pre>", dom, re.S)
    if found is None:
        raise RuntimeError("the page did not report its boxes (no <pre id='go-boxes'> in the DOM)")
    return json.loads(html.unescape(found.group(1)))


def overlaps(boxes: list[dict], tolerance: float = 0.5) -> list[tuple[str, str]]:
    """Pairs of boxes that overlap by more than ``tolerance`` px on both axes, named by their text / class."""
    out = []
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            dx = min(a["x"] + a["w"], b["x"] + b["w"]) - max(a["x"], b["x"])
            dy = min(a["y"] + a["h"], b["y"] + b["h"]) - max(a["y"], b["y"])
            if dx > tolerance and dy > tolerance:
                out.append((_name(a), _name(b)))
    return out


def _name(box: dict) -> str:
    return f"{box['tag'].lower()}.{box['cls']} '{box['text']}' at ({box['x']:.0f}, {box['y']:.0f})"


def save_screenshot(page: Path, png: Path, width: int = WIDTH) -> Path:
    """A screenshot of ``page`` from its top down to below the test-view grid, as a small palette PNG."""
    from PIL import Image

    boxes = layout_boxes(page, width)["boxes"]
    if not boxes:
        raise RuntimeError(f"{page} has no test-view grid laid out in HTML")
    height = int(max(b["y"] + b["h"] for b in boxes)) + 24
    raw = png.with_suffix(".raw.png")
    chromium([f"--window-size={width},{height}", f"--screenshot={raw.resolve()}", page.resolve().as_uri()])
    image = Image.open(raw).convert("RGB")
    raw.unlink()
    image.quantize(256, method=Image.Quantize.MEDIANCUT).save(png, optimize=True)
    return png


def main(out_dir: str) -> None:
    """Write report_grid_{8,20,60}.png into ``out_dir``."""
    from go_pipeline.reporting.render import write_html

    with tempfile.TemporaryDirectory(prefix="go-report-grid-") as tmp:
        for n in (8, 20, 60):
            report = synthetic_report(Path(tmp) / str(n), n)
            page = write_html(report, Path(tmp) / str(n))
            print(save_screenshot(page, Path(out_dir) / f"report_grid_{n}.png"))


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's go_pipeline
    main(sys.argv[1])
