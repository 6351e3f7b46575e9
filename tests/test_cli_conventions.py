"""DVC / nerfstudio conventions (issue 20): params [--diff], dag, gc / clean --dry-run, runs, progress lines
without a terminal."""

from __future__ import annotations

import json

import pytest
from _runner_toy import make_toy_project


@pytest.fixture()
def toy(tmp_path):
    return make_toy_project(tmp_path)


def test_params_lists_defaults_and_current_values(toy):
    base = ["--pipeline", str(toy.pipeline)]
    rows = json.loads(toy.cli("params", *base, "--json").stdout)
    assert {"param": "train.iterations", "default": 30, "current": 30} in rows
    assert len(rows) == 2 + 1 + 2 + 6 + 1  # every param of every step
    assert toy.cli("run", str(toy.scene), *base, "--profile", "quick", "--quiet").returncode == 0
    done = toy.cli("params", str(toy.scene), *base, "--changed")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].split() == ["param", "default", "current"]
    assert lines[1].split() == ["train.iterations", "30", "10"] and len(lines) == 3
    assert lines[2] == "(profile quick, seed 0, --set none)"
    # flags change what is shown, as they would change a run
    rows = json.loads(toy.cli("params", str(toy.scene), *base, "--set", "double.factor=4", "--json").stdout)
    assert {"param": "double.factor", "default": 2.0, "current": 4.0} in rows


def test_params_diff_between_two_work_dirs(toy, tmp_path):
    base = ["--pipeline", str(toy.pipeline), "--quiet"]
    other = tmp_path / "other_wd"
    assert toy.cli("run", str(toy.scene), *base).returncode == 0
    assert (
        toy.cli("run", str(toy.scene), *base, "--workdir", str(other), "--set", "double.factor=3").returncode
        == 0
    )
    done = toy.cli("params", str(toy.scene), "--diff", str(other), "--pipeline", str(toy.pipeline), "--json")
    assert json.loads(done.stdout) == [{"param": "double.factor", "this": 2.0, "other": 3.0}]
    same = toy.cli("params", str(toy.scene), "--diff", str(toy.scene), "--pipeline", str(toy.pipeline))
    assert same.stdout.startswith("no param differs")


def test_dag_prints_steps_in_order_with_inputs_and_outputs(toy):
    done = toy.cli("dag", "--pipeline", str(toy.pipeline))
    lines = done.stdout.splitlines()
    assert [line.split()[1] for line in lines] == ["ingest", "double", "side", "train", "report"]
    assert "<- (scene folder)" in lines[0] and "=> data.json" in lines[0]
    assert "<- train, ingest" in lines[4] and "=> report.txt" in lines[4]
    dot = toy.cli("dag", "--pipeline", str(toy.pipeline), "--dot").stdout
    assert dot.startswith("digraph pipeline {") and '"double" -> "train";' in dot
    graph = json.loads(toy.cli("dag", "--pipeline", str(toy.pipeline), "--json").stdout)
    assert graph["ingest"]["downstream"] == ["double", "side", "report"]


def test_gc_and_clean_dry_run_delete_nothing(toy):
    base = ["--pipeline", str(toy.pipeline), "--quiet"]
    assert toy.cli("run", str(toy.scene), *base).returncode == 0
    assert toy.cli("run", str(toy.scene), *base, "--set", "double.factor=3").returncode == 0
    wd = toy.scene / ".go"
    before = sorted(p.relative_to(wd) for p in wd.rglob("*"))
    dry = toy.cli("gc", str(toy.scene), "--dry-run")
    assert dry.returncode == 0, dry.stderr
    # the old double, train and report artifacts (their inputs changed) would go
    gone = [line.split()[2] for line in dry.stdout.splitlines() if line.startswith("would delete ")]
    assert sorted(p.split("/")[1] for p in gone) == ["double", "report", "train"]
    assert dry.stdout.splitlines()[-1].startswith("dry run: would delete 3 item(s)")
    assert sorted(p.relative_to(wd) for p in wd.rglob("*")) == before
    dry = toy.cli("clean", str(toy.scene), "--dry-run")
    assert (
        "dry run: would delete" in dry.stdout and sorted(p.relative_to(wd) for p in wd.rglob("*")) == before
    )
    # not a terminal: no question; then status is still fresh (gc keeps what the latest run uses)
    done = toy.cli("gc", str(toy.scene))
    assert done.returncode == 0 and "removed 3 item(s)" in done.stderr
    status = toy.cli("status", str(toy.scene), "--pipeline", str(toy.pipeline))
    assert status.stdout.splitlines()[-1] == "everything is up to date"
    assert (
        toy.cli("report", str(toy.scene), "--pipeline", str(toy.pipeline), "--format", "json").returncode == 0
    )


def test_runs_table_shows_differing_params_and_the_current_run(toy):
    base = ["--pipeline", str(toy.pipeline), "--quiet"]
    assert toy.cli("run", str(toy.scene), *base).returncode == 0
    assert toy.cli("run", str(toy.scene), *base).returncode == 0  # a no-op run is not an experiment
    assert toy.cli("run", str(toy.scene), *base, "--set", "double.factor=3", "--seed", "2").returncode == 0
    data = json.loads(toy.cli("runs", str(toy.scene), "--pipeline", str(toy.pipeline), "--json").stdout)
    assert data["differing_params"] == ["double.factor"]
    assert [r["seed"] for r in data["runs"]] == [0, 2]
    assert data["runs"][0]["ran"] == ["ingest", "double", "side", "train", "report"]
    table = toy.cli("runs", str(toy.scene), "--pipeline", str(toy.pipeline)).stdout.splitlines()
    assert (
        table[0].split()[:5] == ["run", "(started,", "UTC)", "profile", "seed"]
        and "double.factor" in table[0]
    )
    assert len(table) == 4 and table[2].split()[4] == "3.0"


def test_progress_lines_without_a_terminal(toy, monkeypatch, capsys):
    """Not a TTY: a progress line with count, percent and fields on stdout every ~10 s, and in the log."""
    from go_pipeline import display as display_mod
    from go_pipeline.runner import run_pipeline

    monkeypatch.setattr(display_mod, "PROGRESS_LINE_EVERY_S", 0.0)
    summary = run_pipeline(toy.scene, pipeline_path=toy.pipeline, overrides={"train.sleep": 0.01})
    log = summary.log_path.read_text()
    assert "[train] train: iterations 30/30 (100%)" in log and " elapsed" in log
    out = capsys.readouterr().out
    assert "  [train] train: iterations " in out and "%), " in out


def test_progress_bar_fields_and_eta():
    from go_pipeline.display import _Bar

    bar = _Bar("coarse: coarse 3DGS", 2000, 0)
    bar.started -= 10.0
    bar.done = 500
    bar.fields.update(loss=0.041234, gaussians=26123)
    line = bar.line()
    assert line.startswith("coarse: coarse 3DGS 500/2000 (25%), 0:10 elapsed, ETA 0:30")
    assert line.endswith("loss 0.04123, 26,123 Gaussians")
