"""The run report as a browser shows it: headless Chromium (Debian's `chromium`) renders the report.html of
the built-in example (test profile) and the screenshot shows its images (benchmarks/report_screenshot.py)."""

from __future__ import annotations

import pytest
from _benchmark_module import benchmark_module


@pytest.mark.slow
def test_report_html_renders_in_headless_chromium(tmp_path):
    shot = benchmark_module("report_screenshot")
    if shot.find_chromium() is None:
        pytest.skip("needs chromium (Debian: apt-get install chromium)")
    from go_pipeline.cli import main

    work = tmp_path / "ex"
    assert main(["run", "--example", "--workdir", str(work), "--profile", "test", "--quiet"]) == 0
    html = work / "basket" / ".go" / "outputs" / "report.html"
    text = html.read_text()
    assert "Test views" in text and "mean |RGB error|" not in text  # the colour bar label is in the image
    assert text.count("data:image/png;base64,") >= 3 and "data:image/gif;base64," in text
    png = shot.screenshot(html, tmp_path / "report.png")
    facts = shot.check_screenshot(png)
    assert (facts["width"], facts["height"]) == (1200, 2400)
    assert facts["non_white_fraction"] > 0.05  # text, tables and images, not a blank page
    assert facts["colourful_fraction"] > 0.005  # the error maps and plots were drawn
