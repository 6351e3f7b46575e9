"""A work dir that remembers its settings (params.yaml), findable results (outputs/), and a report that
refuses artifacts from different runs (issue 20)."""

from __future__ import annotations

import json

import pytest
import yaml
from _runner_toy import make_toy_project

from go_pipeline import outputs, store
from go_pipeline.pipeline import load_pipeline
from go_pipeline.workspace import Settings, describe_changes, load_settings, merge


@pytest.fixture()
def toy(tmp_path):
    return make_toy_project(tmp_path)


def test_run_remembers_profile_set_and_seed(toy):
    base = ["--pipeline", str(toy.pipeline)]
    done = toy.cli("run", str(toy.scene), *base, "--profile", "quick", "--seed", "3")
    assert done.returncode == 0, done.stderr
    saved = yaml.safe_load((toy.scene / ".go" / "params.yaml").read_text())
    assert saved["profile"] == "quick" and saved["seed"] == 3 and saved["set"] == {}
    assert saved["effective"] == {"train": {"iterations": 10}}  # what differs from the defaults
    # status and a plain run use the remembered settings: nothing is stale
    status = toy.cli("status", str(toy.scene), *base)
    assert status.stdout.splitlines()[-1] == "everything is up to date"
    assert status.stderr.startswith("settings (") and "profile quick, seed 3, --set none" in status.stderr
    again = toy.cli("run", str(toy.scene), *base)
    assert "everything is up to date" in again.stderr and "running" not in again.stderr
    # a changed flag says what it changes before running, and is remembered
    changed = toy.cli("run", str(toy.scene), *base, "--set", "train.iterations=12")
    assert changed.returncode == 0, changed.stderr
    lines = changed.stderr.splitlines()
    assert lines[0].startswith("settings changed since the last run (")
    assert lines[1].strip() == "train.iterations 10 -> 12"
    assert lines[2].strip() == "reruns train and the steps after them"
    assert load_settings(toy.scene / ".go") == Settings("quick", {"train.iterations": 12}, 3)
    # --reset-params starts again from pipeline.yaml's defaults (seed 0, no profile, no --set)
    reset = toy.cli("run", str(toy.scene), *base, "--reset-params")
    assert "profile quick -> (none)" in reset.stderr and "seed 3 -> 0 (every step reruns)" in reset.stderr
    assert load_settings(toy.scene / ".go") == Settings(None, {}, 0)


def test_bad_set_is_not_remembered(toy):
    base = ["--pipeline", str(toy.pipeline)]
    assert toy.cli("run", str(toy.scene), *base, "--quiet").returncode == 0
    before = (toy.scene / ".go" / "params.yaml").read_text()
    bad = toy.cli("run", str(toy.scene), *base, "--set", "train.iterations=many")
    assert bad.returncode == 2
    assert (toy.scene / ".go" / "params.yaml").read_text() == before


def test_merge_rules():
    saved = Settings("quick", {"a.b": 1}, 5)
    assert merge(saved, None, {}, None) == saved
    assert merge(saved, "slow", {"a.c": 2}, None) == Settings("slow", {"a.b": 1, "a.c": 2}, 5)
    assert merge(saved, None, {"a.b": 7}, 0) == Settings("quick", {"a.b": 7}, 0)
    assert merge(saved, None, {}, None, reset=True) == Settings(None, {}, 0)
    assert merge(None, None, {}, None, default_profile="example") == Settings("example", {}, 0)


def test_describe_changes_lists_each_param(toy):
    pipeline = load_pipeline(toy.pipeline)
    lines = describe_changes(pipeline, Settings("quick"), Settings("slow"))
    assert lines == [
        "profile quick -> slow",
        "train.iterations 10 -> 60",
        "train.sleep 0.0 -> 0.02",
        "reruns train and the steps after them",
    ]
    assert describe_changes(pipeline, None, Settings("slow")) == []
    assert describe_changes(pipeline, Settings("slow"), Settings("slow")) == []


def test_publish_copies_results_under_stable_names(toy, monkeypatch):
    assert toy.cli("run", str(toy.scene), "--pipeline", str(toy.pipeline), "--quiet").returncode == 0
    wd = toy.scene / ".go"
    monkeypatch.setattr(outputs, "COPIED", {"model.ply": ("train", "model.json")})
    keys = {s: store.read_ref(wd, s) for s in ("ingest", "double", "side", "train", "report")}
    files = outputs.publish(toy.scene, wd, keys, pipeline_path=toy.pipeline)
    out = wd / "outputs"
    assert files == {"model.ply": out / "model.ply", "report.html": out / "report.html"}
    train_dir = store.artifact_path(wd, "train", keys["train"])
    assert (out / "model.ply").read_bytes() == (train_dir / "model.json").read_bytes()
    assert (out / "model.ply").stat().st_mode & 0o044  # readable by others, not a private temp file
    html = (out / "report.html").read_text()
    assert html.startswith("<!doctype html>") and str(out / "model.ply") in html
    index = json.loads((out / "index.json").read_text())
    assert index["keys"] == keys and not list(out.glob(".*tmp*"))
    # unchanged keys: nothing is rewritten
    mtime = (out / "report.html").stat().st_mtime_ns
    outputs.publish(toy.scene, wd, keys, pipeline_path=toy.pipeline)
    assert (out / "report.html").stat().st_mtime_ns == mtime
    # --output DIR
    other = toy.root / "results"
    outputs.publish(toy.scene, wd, keys, output=other, pipeline_path=toy.pipeline)
    assert sorted(p.name for p in other.iterdir()) == ["index.json", "model.ply", "report.html"]


def test_run_prints_where_the_results_are(toy):
    done = toy.cli("run", str(toy.scene), "--pipeline", str(toy.pipeline))
    assert done.returncode == 0, done.stderr
    out = toy.scene / ".go" / "outputs"
    assert (out / "report.html").is_file()
    assert f"report.html  {out / 'report.html'}" in done.stdout or "report.html" in done.stdout
    assert done.stdout.splitlines()[-1].startswith("next: open ")


def test_result_lines_name_the_model_metrics_and_paths(tmp_path):
    metrics = tmp_path / "metrics.json"
    metrics.write_text(
        json.dumps(
            {
                "model": "coarse",
                "model_reason": "repair skipped",
                "mean": {"psnr": 19.944, "ssim": 0.71501, "lpips_star": 22.93},
                "views": [{}] * 8,
            }
        )
    )
    files = {
        "metrics.json": metrics,
        "model.ply": tmp_path / "model.ply",
        "turntable.gif": tmp_path / "turntable.gif",
        "report.html": tmp_path / "report.html",
    }
    lines = outputs.result_lines(None, files, "go-example/basket", "example", cwd=tmp_path)
    assert lines[0] == "result: the coarse model (repair skipped)"
    assert lines[1] == "  8 test views: PSNR 19.94 dB, SSIM 0.7150, LPIPS* 22.93"
    assert lines[2] == "what you got, in ./:"  # one folder, then each file with what it is
    assert [line.split()[0] for line in lines[3:-1]] == [
        "model.ply",
        "report.html",
        "turntable.gif",
        "metrics.json",
    ]
    assert lines[-1].startswith("next: open report.html in a browser, or go-pipeline run go-example/basket")


def test_report_refuses_artifacts_from_different_runs(toy, tmp_path):
    base = ["--pipeline", str(toy.pipeline), "--quiet"]
    assert toy.cli("run", str(toy.scene), *base).returncode == 0
    ok = toy.cli("report", str(toy.scene), "--pipeline", str(toy.pipeline), "-o", str(tmp_path / "r.html"))
    assert ok.returncode == 0, ok.stderr
    assert (tmp_path / "r.html").read_text().startswith("<!doctype html>")
    # a partial run changes `double`: `train` (current ref) was made from the old `double`
    assert (
        toy.cli("run", str(toy.scene), *base, "--set", "double.factor=3", "--until", "double").returncode == 0
    )
    refused = toy.cli("report", str(toy.scene), "--pipeline", str(toy.pipeline), "--format", "json")
    assert refused.returncode == 2
    assert "the artifacts come from different runs: train was made from another double artifact" in (
        refused.stderr
    )
    shown = toy.cli(
        "report", str(toy.scene), "--pipeline", str(toy.pipeline), "--format", "json", "--allow-mixed"
    )
    assert shown.returncode == 0 and "WARNING: mixed runs: train was made from another double" in shown.stderr
    assert json.loads(shown.stdout)["warnings"]
    md = toy.cli("report", str(toy.scene), "-o", str(tmp_path / "m" / "report.md"), "--allow-mixed")
    assert md.returncode == 0 and "**WARNING:**" in (tmp_path / "m" / "report.md").read_text()
