"""Batch runs on a local 2-CPU Ray instance: one broken scene is reported, the others finish."""

from __future__ import annotations

import csv
import importlib.util
import json
import os

import pytest
from _eval_toy import make_eval_toy

from go_pipeline.reporting.batch import find_scenes, run_batch, write_results
from go_pipeline.reporting.run_report import validate_report

# not imported here: the batch sets RAY_AUTH_MODE before Ray's first import (a local cluster, no warning)
pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("ray") is None, reason="needs the [ray] extra: pip install -e '.[ray]'"
)


def test_ray_batch_with_a_broken_scene(tmp_path, monkeypatch):
    toy = make_eval_toy(tmp_path)
    root = tmp_path / "dataset"
    toy.scene(root, "a", "1")
    toy.scene(root, "b_broken", "not-a-number")
    toy.scene(root, "c", "3")
    (root / ".hidden").mkdir()
    # Ray workers (and the runner's step processes) must import the toy step package
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(toy.src), os.environ.get("PYTHONPATH", "")]))
    assert [p.name for p in find_scenes(root)] == ["a", "b_broken", "c"]
    # steps in the Ray worker process itself (in_process): saves a torch import per step in CI
    options = {"pipeline_path": str(toy.pipeline), "workdir_root": str(tmp_path / "wd"), "in_process": True}
    result = run_batch(root, num_cpus=2, options=options)  # starts (and stops) a local 2-CPU Ray
    assert result.ray["cluster_cpus"] == 2.0
    status = {r["scene"]: r["status"] for r in result.rows}
    assert status == {"a": "ok", "b_broken": "failed", "c": "ok"}
    broken = next(r for r in result.rows if r["scene"] == "b_broken")
    assert "seed.txt is not an integer" in broken["error"]
    for r in result.rows:
        if r["status"] == "ok":
            validate_report(r["report"])
            assert r["report"]["metrics"]["mean"]["psnr"] > 45

    paths = write_results(result, tmp_path / "out")
    with open(paths["csv"]) as f:
        rows = list(csv.DictReader(f))
    assert [r["scene"] for r in rows] == ["a", "b_broken", "c"]
    assert float(rows[0]["psnr"]) > 45 and rows[1]["psnr"] == "" and rows[1]["status"] == "failed"
    assert float(rows[2]["wall_s_eval"]) > 0
    data = json.loads(paths["json"].read_text())
    assert data["aggregate"]["ok"] == 2 and data["aggregate"]["failed"] == 1
    assert data["aggregate"]["mean_psnr"] == pytest.approx(
        (float(rows[0]["psnr"]) + float(rows[2]["psnr"])) / 2
    )
    assert "b_broken" in paths["md"].read_text()

    # cache-aware: a second batch reruns nothing for the good scenes (tasks run in-process here to save a
    # second Ray start-up; the Ray path was exercised above)
    from go_pipeline.reporting.batch import run_scene

    for name in ("a", "c"):
        r = run_scene(str(root / name), options)
        assert r["status"] == "ok" and r["ran"] == [] and set(r["cached"]) == {"scene", "coarse", "eval"}, r
