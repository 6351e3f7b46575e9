"""A headless-browser screenshot of a run's report.html (Chromium from Debian: `apt-get install chromium`),
checked for what a reader must see: the page renders, with its images (not a blank or broken page).

    python benchmarks/archive/report_screenshot.py go-example/basket/.go/outputs/report.html \
        docs/img/report.png

Writes the PNG and prints a JSON line of the checks (size, share of non-white pixels, colourfulness).
The slow test tests/test_report_screenshot.py runs the same checks on a freshly built report; the browser
helpers live in tests/_browser.py.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository: tests/_browser.py
from tests._browser import check_screenshot, screenshot  # noqa: E402


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
