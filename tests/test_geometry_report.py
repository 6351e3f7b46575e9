"""The report and the batch table show eval's geometry: the final and hull meshes' figures, or why none."""

from __future__ import annotations

from go_pipeline.reporting.batch import geometry_columns
from go_pipeline.reporting.render import geometry_rows
from go_pipeline.reporting.run_report import geometry_block

GEOMETRY = {
    "status": "ok",
    "protocol": {"samples_per_surface": 300000, "seed": 0, "fscore_thresholds": "1% and 2% of r"},
    "final": {"chamfer_l1": 0.01, "fscore_1pct": 0.5, "fscore_2pct": 0.8, "normal_consistency": 0.9,
              "silhouette_iou": 0.95, "accuracy": 0.01},
    "hull": {"chamfer_l1": 0.04, "fscore_1pct": 0.2, "fscore_2pct": 0.4, "normal_consistency": 0.8,
             "silhouette_iou": 0.9, "accuracy": 0.05},
}  # fmt: skip


def test_geometry_reaches_the_report_and_the_batch_table():
    block = geometry_block(GEOMETRY)
    assert block["meshes"]["final"]["chamfer_l1"] == 0.01 and "accuracy" not in block["meshes"]["final"]
    report = {"metrics": {"geometry": block}}
    rows, note = geometry_rows(report)
    assert [r[0] for r in rows] == ["final", "hull"] and rows[1][1] == "0.0400"
    assert "300000 points per surface (seed 0)" in note
    cols = geometry_columns(report)
    assert cols == {"chamfer_l1": 0.01, "fscore_1pct": 0.5, "hull_chamfer_l1": 0.04, "hull_fscore_1pct": 0.2}


def test_no_geometry_says_why():
    skipped = geometry_block({"status": "skipped", "reason": "the scene has no ground-truth mesh_world.npz"})
    rows, note = geometry_rows({"metrics": {"geometry": skipped}})
    assert rows == [] and note == "no geometry metrics: the scene has no ground-truth mesh_world.npz"
    assert geometry_block(None) is None and geometry_rows({"metrics": None}) == ([], "")
    assert set(geometry_columns({})) == {"chamfer_l1", "fscore_1pct", "hull_chamfer_l1", "hull_fscore_1pct"}
