"""A newcomer's first hour (issue 20): no leftovers from failed or no-op runs, argument errors that name no
file, no traceback on a closed pipe, a clear error for --device cuda without CUDA."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from _runner_toy import make_toy_project

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture()
def toy(tmp_path):
    return make_toy_project(tmp_path)


def test_noop_run_writes_no_log_file(toy):
    base = ["--pipeline", str(toy.pipeline)]
    first = toy.cli("run", str(toy.scene), *base)
    assert first.returncode == 0, first.stderr
    logs = sorted((toy.scene / ".go" / "logs").glob("run-*.log"))
    assert len(logs) == 1 and "log: " in first.stderr
    again = toy.cli("run", str(toy.scene), *base)
    assert again.returncode == 0, again.stderr
    assert sorted((toy.scene / ".go" / "logs").glob("run-*.log")) == logs
    assert "everything is up to date" in again.stderr and "log: " not in again.stderr
    # a run that does something writes its own log again
    assert toy.cli("run", str(toy.scene), *base, "--set", "double.factor=3").returncode == 0
    assert len(list((toy.scene / ".go" / "logs").glob("run-*.log"))) == 2


def test_failed_first_run_leaves_no_workdir(toy, tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    (photos / "x.dat").write_text("not a scene")
    done = toy.cli("run", str(photos), "--pipeline", str(toy.pipeline), "--quiet")
    assert done.returncode == 2 and "no .txt files" in done.stderr
    assert sorted(p.name for p in photos.iterdir()) == ["x.dat"]  # no .go/ left behind


def test_failed_later_run_keeps_the_cached_steps(toy):
    base = ["--pipeline", str(toy.pipeline), "--quiet"]
    assert toy.cli("run", str(toy.scene), *base).returncode == 0
    done = toy.cli("run", str(toy.scene), *base, "--set", "train.fail_at=2")
    assert done.returncode == 1
    assert (toy.scene / ".go" / "artifacts" / "ingest").is_dir()


def test_failed_run_is_listed_by_runs(toy):
    """A run that stopped before its end (a step failed, Ctrl-C) is in the experiments table, saying so."""
    base = ["--pipeline", str(toy.pipeline)]
    assert toy.cli("run", str(toy.scene), *base, "--quiet").returncode == 0
    assert toy.cli("run", str(toy.scene), *base, "--quiet", "--set", "train.fail_at=2").returncode == 1
    data = json.loads(toy.cli("runs", str(toy.scene), *base, "--json").stdout)
    assert [r["status"] for r in data["runs"]] == ["finished", "failed"]
    table = toy.cli("runs", str(toy.scene), *base).stdout
    assert "failed" in table


def test_crashed_first_run_keeps_its_log(toy):
    """A step crash names the log holding its traceback, so that log must survive."""
    done = toy.cli("run", str(toy.scene), "--pipeline", str(toy.pipeline), "--set", "train.fail_at=2")
    assert done.returncode == 1
    log = done.stderr.strip().rsplit("traceback in ", 1)[1]
    assert Path(log).is_file() and "boom at iteration 2" in Path(log).read_text()


def test_closed_pipe_gives_no_traceback(toy):
    """`go-pipeline status --json | head -0`: stdout's reader is gone before anything is written."""
    assert toy.cli("run", str(toy.scene), "--pipeline", str(toy.pipeline), "--quiet").returncode == 0
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        done = subprocess.run(
            [sys.executable, "-m", "go_pipeline.cli", "status", str(toy.scene), "--json"]
            + ["--pipeline", str(toy.pipeline)],
            env=toy.env(),
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            timeout=60,
        )
    finally:
        os.close(write_end)
    assert done.returncode == 141, done.stderr
    assert done.stderr == ""


def test_device_cuda_without_cuda_is_an_error(toy):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    done = toy.cli("run", str(toy.scene), "--pipeline", str(toy.pipeline), "--device", "cuda")
    assert done.returncode == 2
    assert done.stderr.strip().startswith("error: --device cuda: CUDA is not available (")
    assert not (toy.scene / ".go").exists()


def test_example_folder_is_git_ignored():
    patterns = (REPO / ".gitignore").read_text().split()
    assert "/go-example/" in patterns or "go-example/" in patterns


AFTER = """
import json
VERSION = "1"
SKIP_IF_SKIPPED = ("s",)

def run(ctx, inputs, params):
    (ctx.out_dir / "after.json").write_text(json.dumps({"status": "ok"}))
    (ctx.out_dir / "after.npz").write_bytes(b"")
    ctx.record(status="ok")
"""


def test_runner_skips_without_a_worker(toy, monkeypatch):
    """A step declaring SKIP_IF_SKIPPED is skipped by the runner when that input skipped: no worker
    process, its .json / .npz outputs written for it, a short reason naming the root step."""
    import numpy as np

    from go_pipeline import executor
    from go_pipeline.runner import run_pipeline

    toy.step_file("after").write_text(AFTER)
    toy.pipeline.write_text(
        toy.pipeline.read_text().replace(
            "profiles:",
            f"  after:\n    function: {toy.pkg}.after:run\n    inputs: {{s: side}}\n"
            "    outputs: [after.json, after.npz]\n    params: {}\nprofiles:",
        )
    )
    started = []
    real = executor.execute
    monkeypatch.setattr(
        executor, "execute", lambda job, *a, **k: started.append(job["step"]) or real(job, *a, **k)
    )
    summary = run_pipeline(toy.scene, pipeline_path=toy.pipeline, overrides={"side.skip": True}, quiet=True)
    after = summary.step("after")
    assert after.status == "skipped" and "after" not in started and "side" in started
    assert after.record["reason"] == "label says skip (see the side step)"
    assert json.loads((after.artifact_dir / "after.json").read_text())["status"] == "skipped"
    assert len(np.load(after.artifact_dir / "after.npz").files) == 0
    # (the skip follows the upstream's record; its output must differ too, as weights.json does)
    summary = run_pipeline(toy.scene, pipeline_path=toy.pipeline, overrides={"side.label": "x"}, quiet=True)
    assert summary.step("after").status == "ran" and "after" in started


def test_runner_skips_on_an_empty_param_without_a_worker(toy, monkeypatch):
    """SKIP_IF_EMPTY = {param: reason}: the step is skipped by the runner while that param is empty."""
    from go_pipeline import executor
    from go_pipeline.runner import run_pipeline

    toy.step_file("after").write_text(
        AFTER.replace('SKIP_IF_SKIPPED = ("s",)', 'SKIP_IF_EMPTY = {"model": "no model configured"}')
    )
    toy.pipeline.write_text(
        toy.pipeline.read_text().replace(
            "profiles:",
            f"  after:\n    function: {toy.pkg}.after:run\n    inputs: {{s: side}}\n"
            "    outputs: [after.json, after.npz]\n    params: {model: ''}\nprofiles:",
        )
    )
    started = []
    real = executor.execute
    monkeypatch.setattr(
        executor, "execute", lambda job, *a, **k: started.append(job["step"]) or real(job, *a, **k)
    )
    summary = run_pipeline(toy.scene, pipeline_path=toy.pipeline, quiet=True)
    assert summary.step("after").status == "skipped" and "after" not in started
    assert summary.step("after").record["reason"] == "no model configured"
    summary = run_pipeline(toy.scene, pipeline_path=toy.pipeline, overrides={"after.model": "m"}, quiet=True)
    assert summary.step("after").status == "ran" and "after" in started


def test_depth_step_declares_its_runner_skip():
    from go_pipeline.steps.registry import DEPTH_SKIP_REASON, STEPS

    from go_pipeline.skipping import param_skip

    rule = STEPS["go_pipeline.steps.depth"].skip_if_empty
    record = param_skip(rule, {"model_path": ""})
    assert record["status"] == "skipped" and record["reason"] == DEPTH_SKIP_REASON
    assert param_skip(rule, {"model_path": "/models/dpt"}) is None
