"""Run reports: JSON follows data_schema/run_report.schema.json; md/html carry images and plots."""

from __future__ import annotations

import json

import jsonschema
import pytest
from _eval_toy import make_eval_toy
from PIL import Image

from go_pipeline.reporting.render import write_html, write_markdown
from go_pipeline.reporting.run_report import build_report, validate_report
from go_pipeline.runner import run_pipeline


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("report")
    toy = make_eval_toy(tmp)
    scene = toy.scene(tmp, "scene1", "5")
    wd = tmp / "wd"
    run_pipeline(
        scene,
        workdir=wd,
        pipeline_path=toy.pipeline,
        overrides={"coarse.color_noise": 0.2},
        in_process=True,
        quiet=True,
    )
    return scene, wd, toy


def test_report_json_validates_and_matches_artifacts(ran):
    scene, wd, toy = ran
    report = build_report(scene, wd, toy.pipeline)
    validate_report(report)
    assert [s["name"] for s in report["steps"]] == ["scene", "coarse", "eval"]
    assert report["totals"]["wall_s"] == pytest.approx(sum(s["wall_s"] for s in report["steps"]))
    assert all(s["cpu_s"] >= 0 and s["peak_mem_mb"] > 0 for s in report["steps"])
    assert report["device"] == "cpu" and "torch" in report["versions"]["libraries"]
    assert report["result"] == {
        "model": "coarse",
        "reason": "no repair step in this pipeline",
        "repair_ran": False,
        "repair_status": None,
        "num_gaussians": 300,
    }
    from go_pipeline import store

    metrics = json.loads((store.artifact_dir(wd, "eval") / "metrics.json").read_text())
    assert report["metrics"]["mean"]["psnr"] == metrics["mean"]["psnr"]
    assert len(report["metrics"]["views"]) == 3
    # the schema really constrains: a missing key or a wrong type is refused
    broken = dict(report)
    del broken["totals"]
    with pytest.raises(jsonschema.ValidationError):
        validate_report(broken)
    with pytest.raises(jsonschema.ValidationError):
        validate_report({**report, "result": {**report["result"], "model": "fine"}})


def test_report_markdown_and_html(ran, tmp_path):
    scene, wd, toy = ran
    report = build_report(scene, wd, toy.pipeline)
    md = write_markdown(report, tmp_path / "md")
    text = md.read_text()
    assert "![test views](test_grid.png)" in text and "| eval |" in text and "PSNR" in text
    for name in ("test_grid.png", "steps.png", "views.png"):
        assert Image.open(tmp_path / "md" / name).size[0] > 50
    # the grid is redrawn labelled (view names, row names, an error colour bar): larger than the raw grid
    raw = Image.open(report["images"]["test_grid"]).size
    labelled = Image.open(tmp_path / "md" / "test_grid.png").size
    assert labelled[1] > raw[1]
    page = write_html(report, tmp_path / "html").read_text()  # one self-contained file
    assert "<h2>Test views</h2>" in page and "<img src='data:image/png;base64," in page and "<table" in page
    assert sorted(p.name for p in (tmp_path / "html").iterdir()) == ["report.html"]


def test_report_cli_json(ran, capsys):
    from go_pipeline.cli import main

    scene, wd, toy = ran
    assert (
        main(
            ["report", str(scene), "--workdir", str(wd), "--pipeline", str(toy.pipeline), "--format", "json"]
        )
        == 0
    )
    validate_report(json.loads(capsys.readouterr().out))


def test_report_open_writes_the_html_report_and_opens_it(ran, capsys, monkeypatch):
    from pathlib import Path

    from go_pipeline.cli import main

    scene, wd, toy = ran
    opened = []
    monkeypatch.setattr("webbrowser.open", lambda url: opened.append(url) or True)
    assert main(["report", str(scene), "--workdir", str(wd), "--pipeline", str(toy.pipeline), "--open"]) == 0
    path = Path(capsys.readouterr().out.strip().splitlines()[-1])
    assert path.name == "report.html" and path.is_file() and opened == [path.resolve().as_uri()]


def test_report_names_the_published_outputs_not_the_artifact_paths(ran, capsys):
    from go_pipeline import store
    from go_pipeline.cli import main
    from go_pipeline.outputs import publish

    scene, wd, toy = ran
    keys = {s: store.read_ref(wd, s) for s in ("scene", "coarse", "eval")}
    publish(scene, wd, keys, pipeline_path=toy.pipeline)
    args = ["report", str(scene), "--workdir", str(wd), "--pipeline", str(toy.pipeline), "--format", "json"]
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    validate_report(report)
    assert report["outputs"]["metrics.json"] == str(wd / "outputs" / "metrics.json")


def test_report_without_artifacts_is_a_clear_error(tmp_path, capsys):
    from go_pipeline.cli import main

    (tmp_path / "empty").mkdir()
    assert main(["report", str(tmp_path / "empty")]) == 2
    assert "no artifacts yet" in capsys.readouterr().err


def test_speed_error_sweep_tiny(tmp_path):
    """The speed-vs-error benchmark on the toy pipeline: every point scored, a Pareto front, a PNG."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(
        "speed_error", Path(__file__).resolve().parents[1] / "benchmarks" / "speed_error.py"
    )
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.pareto(
        [{"t": 1, "e": 3}, {"t": 2, "e": 1}, {"t": 3, "e": 2}, {"t": 1, "e": 4}], "t", "e"
    ) == [0, 1]

    toy = make_eval_toy(tmp_path)
    scene = toy.scene(tmp_path, "sweep", "7")
    out = tmp_path / "out"
    rc = bench.main(
        [
            str(scene),
            "--pipeline",
            str(toy.pipeline),
            "--grid",
            "coarse.color_noise=0.0,0.4",
            "--ablation",
            "small:scene.size=24",
            "--out",
            str(out),
            "--in-process",
        ]
    )
    assert rc == 0
    data = json.loads((out / "speed_error.json").read_text())
    assert len(data["points"]) == 4 and all(p["status"] == "ok" for p in data["points"])
    by_label = {p["label"]: p for p in data["points"]}
    assert by_label["color_noise=0.0"]["psnr"] > by_label["color_noise=0.4"]["psnr"]
    assert data["pareto"]["psnr"] and Image.open(out / "speed_error.png").size[0] > 500
