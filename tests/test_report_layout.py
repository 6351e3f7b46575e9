"""report.html's test-view grid as headless Chromium lays it out, at 8, 20 and 60 test views: no label,
image or colour-bar box overlaps another, none leaves the window, and each view's title sits over its own
images. Synthetic reports (tests/_report_layout.py), no pipeline run: seconds."""

from __future__ import annotations

import pytest
from _report_layout import WIDTH, find_chromium, layout_boxes, overlaps, synthetic_report

from go_pipeline.reporting.grid import PER_BAND, ROW_LABELS
from go_pipeline.reporting.render import write_html
from go_pipeline.reporting.run_report import validate_report

pytestmark = pytest.mark.skipif(
    find_chromium() is None, reason="needs chromium on PATH (Debian: apt-get install chromium)"
)


def _grid_boxes(tmp_path, n_views: int) -> tuple[list[dict], int]:
    report = synthetic_report(tmp_path / "run", n_views)
    validate_report(report)  # the fake report is a real one as far as the schema knows
    page = write_html(report, tmp_path / "html")
    found = layout_boxes(page)
    return found["boxes"], found["viewport"]


@pytest.mark.parametrize("n_views", [8, 20, 60])
def test_report_grid_has_no_overlap(tmp_path, n_views):
    boxes, viewport = _grid_boxes(tmp_path, n_views)
    images = [b for b in boxes if b["tag"] == "IMG"]
    titles = [b for b in boxes if b["cls"] == "tv-name"]
    bands = -(-n_views // PER_BAND)
    assert len(images) == 3 * n_views and len(titles) == n_views
    assert [b["text"] for b in boxes if b["cls"] == "tv-row"] == list(ROW_LABELS) * bands
    assert any(b["cls"] == "tv-ramp" and b["w"] > 50 for b in boxes)  # the colour bar is drawn
    assert all(b["w"] > 40 and b["h"] > 40 for b in images), "thumbnails shrunk to nothing"
    assert viewport == WIDTH
    outside = [b for b in boxes if b["x"] < 0 or b["x"] + b["w"] > viewport]
    assert not outside, f"boxes beyond the {viewport} px window: {outside[:3]}"
    clashes = overlaps(boxes)
    assert not clashes, f"{len(clashes)} overlapping pairs, e.g. {clashes[:3]}"
    for title in titles:  # each title is centred over its own column of three images, and above them
        own = [b for b in images if b["view"] == title["view"]]
        centre = title["x"] + title["w"] / 2
        assert len(own) == 3 and all(b["x"] < centre < b["x"] + b["w"] for b in own), title
        assert all(b["y"] >= title["y"] + title["h"] for b in own), title


def test_overlap_check_catches_a_broken_layout(tmp_path):
    """The check can fail: error rows pulled up into the next band's titles and the colour bar pulled up
    over the last band (the layout bugs of issue 82) are reported as overlaps."""
    report = synthetic_report(tmp_path / "run", 20)
    page = write_html(report, tmp_path / "html")
    broken = ".tv-grid{row-gap:0}.tv-name{margin-top:-40px}.tv-bar{margin-top:-60px}</style>"
    page.write_text(page.read_text().replace("</style>", broken, 1))
    clashes = overlaps(layout_boxes(page)["boxes"])
    assert any("tv-name" in a + b and "|render - GT|" in a + b for a, b in clashes), clashes[:5]
    assert any("tv-ramp" in a + b for a, b in clashes), clashes[:5]
