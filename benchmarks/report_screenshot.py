"""A headless-browser screenshot of a run's report.html (Chromium from Debian: `apt-get install chromium`),
checked for what a reader must see: the page renders, with its images (not a blank or broken page).

    python benchmarks/report_screenshot.py go-example/basket/.go/outputs/report.html docs/img/report.png

Writes the PNG and prints a JSON line of the checks (size, share of non-white pixels, colourfulness).
The slow test tests/test_report_screenshot.py runs the same checks on a freshly built report.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
]


def find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


def screenshot(html: Path, png: Path, width: int = 1200, height: int = 2400, timeout: float = 120) -> Path:
    """Render ``html`` in headless Chromium (a fresh profile) and save a ``width`` x ``height`` PNG."""
    browser = find_chromium()
    if browser is None:
        raise RuntimeError("chromium not found (Debian: apt-get install chromium)")
    png.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="go-chromium-") as profile:
        cmd = [
            browser,
            *CHROMIUM_FLAGS,
            f"--user-data-dir={profile}",
            f"--window-size={width},{height}",
            f"--screenshot={png.resolve()}",
            html.resolve().as_uri(),
        ]
        subprocess.run(cmd, check=True, capture_output=True, timeout=timeout)
    if not png.is_file():
        raise RuntimeError(f"chromium wrote no screenshot to {png}")
    return png


def check_screenshot(png: Path) -> dict:
    """Facts of a screenshot: size, share of non-white pixels and of colourful pixels (images shown)."""
    from PIL import Image

    rgb = np.asarray(Image.open(png).convert("RGB")).astype(np.int16)
    non_white = (rgb.min(axis=-1) < 240).mean()
    colourful = ((rgb.max(axis=-1) - rgb.min(axis=-1)) > 40).mean()
    return {
        "png": str(png),
        "width": int(rgb.shape[1]),
        "height": int(rgb.shape[0]),
        "non_white_fraction": round(float(non_white), 4),
        "colourful_fraction": round(float(colourful), 4),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("html", type=Path)
    p.add_argument("png", type=Path)
    p.add_argument("--width", type=int, default=1200)
    p.add_argument("--height", type=int, default=2400)
    args = p.parse_args(argv)
    screenshot(args.html, args.png, args.width, args.height)
    facts = check_screenshot(args.png)
    print(json.dumps(facts))
    ok = facts["non_white_fraction"] > 0.05 and facts["colourful_fraction"] > 0.01
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
