"""kill -9 of a running ``go-pipeline run`` at random moments (and mid-step, after a checkpoint): the rerun
completes and its final artifacts have exactly the content hashes of an uninterrupted run."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time

import pytest
from _runner_toy import content_hashes, make_toy_project

from go_pipeline import store

ARGS = ["--set", "train.iterations=40", "--set", "train.sleep=0.025", "--set", "train.checkpoint_every=4"]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted run: its content hashes and its duration."""
    toy = make_toy_project(tmp_path_factory.mktemp("ref"))
    t0 = time.perf_counter()
    done = toy.cli("run", str(toy.scene), "--pipeline", str(toy.pipeline), *ARGS)
    assert done.returncode == 0, done.stderr
    return toy, content_hashes(toy.scene / ".go"), time.perf_counter() - t0


def start(toy, workdir, new_session=False) -> subprocess.Popen:
    cmd = [
        sys.executable,
        "-m",
        "go_pipeline.cli",
        "run",
        str(toy.scene),
        "--pipeline",
        str(toy.pipeline),
        "--workdir",
        str(workdir),
        *ARGS,
    ]
    return subprocess.Popen(
        cmd, env=toy.env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=new_session
    )


def finish(toy, workdir):
    done = toy.cli("run", str(toy.scene), "--pipeline", str(toy.pipeline), "--workdir", str(workdir), *ARGS)
    assert done.returncode == 0, done.stderr
    return done


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_kill_at_random_moment_then_rerun(reference, tmp_path, seed):
    toy, ref_hashes, duration = reference
    workdir = tmp_path / f"w{seed}"
    delay = random.Random(seed).uniform(0.05, duration)
    proc = start(toy, workdir, new_session=seed % 2 == 1)
    time.sleep(delay)
    if seed % 2 == 1:
        os.killpg(proc.pid, signal.SIGKILL)  # the whole group, like closing the terminal
    else:
        os.kill(proc.pid, signal.SIGKILL)  # only the CLI: its step process must die with it
    proc.wait()
    finish(toy, workdir)
    assert content_hashes(workdir) == ref_hashes
    assert not list(workdir.glob("artifacts/*/.tmp-*"))


def test_kill_mid_step_resumes_from_checkpoint(reference, tmp_path):
    toy, ref_hashes, _ = reference
    workdir = tmp_path / "w"
    proc = start(toy, workdir)
    deadline = time.monotonic() + 30
    while not list(workdir.glob("checkpoints/train/*/ckpt-*.json")):
        assert proc.poll() is None and time.monotonic() < deadline, "train never checkpointed"
        time.sleep(0.01)
    time.sleep(0.05)
    children = [int(c) for c in open(f"/proc/{proc.pid}/task/{proc.pid}/children").read().split()]
    assert len(children) == 1  # the step process
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    deadline = time.monotonic() + 5
    while any(_alive(c) for c in children):  # the step process dies with the CLI (PR_SET_PDEATHSIG)
        assert time.monotonic() < deadline, "the step process outlived the killed CLI"
        time.sleep(0.01)
    assert store.artifact_dir(workdir, "train") is None  # killed before it finished
    done = finish(toy, workdir)
    manifest = store.load_manifest(store.artifact_dir(workdir, "train"))
    assert manifest["record"]["resumed_from"] >= 4  # really resumed mid-step
    # ... and says so; the killed run is in the experiments table
    said = [line for line in done.stderr.splitlines() if "resuming from checkpoint" in line]
    assert len(said) == 1 and said[0].split()[0] == "train", done.stderr
    runs = toy.cli(
        "runs", str(toy.scene), "--pipeline", str(toy.pipeline), "--workdir", str(workdir), "--json"
    )
    assert [r["status"] for r in json.loads(runs.stdout)["runs"]] == ["killed", "finished"]
    assert content_hashes(workdir) == ref_hashes


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False
