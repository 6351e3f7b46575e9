"""The ``go-pipeline`` command: one-line errors with exit codes, status output, lazy imports, the example."""

from __future__ import annotations

import json
import shutil
import sys

import pytest
from _runner_toy import make_toy_project

from go_pipeline.lock import WorkdirLock
from go_pipeline.resources import example_scene_path


@pytest.fixture()
def toy(tmp_path):
    return make_toy_project(tmp_path)


def one_error_line(done) -> str:
    """The CLI failed with exactly one stderr line, 'error: ...', and no traceback."""
    lines = done.stderr.strip().splitlines()
    assert "Traceback" not in done.stderr, done.stderr
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("error: ")
    return lines[0]


BAD_RUNS = [
    (
        ["--set", "train.iters=5"],
        "--set train.iters=5: step 'train' has no param 'iters' (params: iterations, sleep, "
        "checkpoint_every, fail_at, tags, extra)",
    ),
    (
        ["--set", "train.iterations=many"],
        "--set train.iterations='many': expected int (default 30), got str",
    ),
    (
        ["--set", "train.iterations=2.5"],
        "--set train.iterations=2.5: expected int (default 30), got float",
    ),
    (
        ["--set", "nope.x=1"],
        "--set nope.x=1: unknown step 'nope' (steps: ingest, double, side, train, report)",
    ),
    (["--set", "train.iterations"], "--set train.iterations: expected STEP.PARAM=VALUE"),
    (
        ["--until", "nope"],
        "--until: unknown step 'nope' (steps: ingest, double, side, train, report)",
    ),
    (
        ["--force", "nope"],
        "--force: unknown step 'nope' (steps: ingest, double, side, train, report)",
    ),
    (["--profile", "turbo"], "--profile turbo: unknown profile (profiles: quick, slow)"),
]


@pytest.mark.parametrize("args,message", BAD_RUNS, ids=[" ".join(a) for a, _ in BAD_RUNS])
def test_bad_run_arguments(toy, args, message):
    done = toy.cli("run", str(toy.scene), "--pipeline", str(toy.pipeline), *args)
    assert done.returncode == 2
    assert one_error_line(done) == "error: " + message.format(pipeline=toy.pipeline)
    assert not (toy.scene / ".go" / "artifacts").exists()  # nothing written


def test_missing_scene_and_cyclic_pipeline(toy, tmp_path):
    done = toy.cli("run", str(tmp_path / "nope"), "--pipeline", str(toy.pipeline))
    assert done.returncode == 2
    assert one_error_line(done) == f"error: {tmp_path / 'nope'}: scene folder not found"
    text = toy.pipeline.read_text().replace("inputs: {data: double}", "inputs: {data: report}")
    cyclic = tmp_path / "cyclic.yaml"
    cyclic.write_text(text)
    done = toy.cli("status", str(toy.scene), "--pipeline", str(cyclic))
    assert done.returncode == 2
    assert one_error_line(done) == f"error: {cyclic}: cycle in step inputs: train -> report -> train"


def test_step_errors_exit_codes_and_debug(toy):
    done = toy.cli(
        "run", str(toy.scene), "--pipeline", str(toy.pipeline), "--set", "train.fail_at=3", "--quiet"
    )
    assert done.returncode == 1
    line = one_error_line(done)
    assert line.startswith("error: step 'train' failed: RuntimeError: boom at iteration 3; traceback in ")
    debug = toy.cli(
        "run", str(toy.scene), "--pipeline", str(toy.pipeline), "--set", "train.fail_at=3", "--debug"
    )
    assert debug.returncode == 1 and 'raise RuntimeError(f"boom at iteration {it}")' in debug.stderr
    (toy.scene / "a.txt").unlink()
    (toy.scene / "b.txt").unlink()
    (toy.scene / "x.dat").write_text("")
    done = toy.cli("run", str(toy.scene), "--pipeline", str(toy.pipeline), "--quiet")
    assert done.returncode == 2
    assert one_error_line(done) == f"error: {toy.scene}: no .txt files in the scene folder"


def test_lock_contention_message(toy):
    wd = toy.scene / ".go"
    with WorkdirLock(wd):
        done = toy.cli("run", str(toy.scene), "--pipeline", str(toy.pipeline))
    assert done.returncode == 2
    assert one_error_line(done).startswith(f"error: {wd / 'lock'}: another `go-pipeline run` (pid ")


def test_lock_message_names_clean(toy):
    """The holder's command is named: a `clean` holding the lock is not called a run."""
    wd = toy.scene / ".go"
    with WorkdirLock(wd, command="clean"):
        done = toy.cli("run", str(toy.scene), "--pipeline", str(toy.pipeline))
    assert done.returncode == 2
    assert one_error_line(done).startswith(f"error: {wd / 'lock'}: another `go-pipeline clean` (pid ")


def test_run_status_clean_roundtrip(toy):
    base = ["--pipeline", str(toy.pipeline)]
    done = toy.cli("status", str(toy.scene), *base)
    assert done.returncode == 0
    assert done.stdout.splitlines()[0].split() == ["ingest", "missing", "(never", "run)"]
    assert toy.cli("run", str(toy.scene), *base).returncode == 0
    done = toy.cli("status", str(toy.scene), *base, "--set", "double.factor=3")
    lines = done.stdout.splitlines()
    assert lines[1].split(None, 2) == ["double", "stale", "(param factor changed 2.0 -> 3.0)"]
    assert lines[-1] == "2 fresh, 3 to run"
    rows = json.loads(toy.cli("status", str(toy.scene), *base, "--json").stdout)
    assert [r["state"] for r in rows] == ["fresh"] * 5 and all(len(r["key"]) == 64 for r in rows)
    assert toy.cli("clean", str(toy.scene), "--step", "report").returncode == 0
    rows = json.loads(toy.cli("status", str(toy.scene), *base, "--json").stdout)
    assert rows[-1]["state"] == "missing"
    done = toy.cli("clean", str(toy.scene), "--step", "bogus")
    assert done.returncode == 2 and "--step bogus: unknown step" in one_error_line(done)


def test_noop_run_imports_no_torch(toy):
    """A second run of a finished scene must stay fast: no torch / ray / step import in the CLI process."""
    assert toy.cli("run", str(toy.scene), "--pipeline", str(toy.pipeline)).returncode == 0
    code = (
        "import sys; from go_pipeline.cli import main; "
        f"rc = main(['run', {str(toy.scene)!r}, '--pipeline', {str(toy.pipeline)!r}]); "
        "heavy = sorted(m for m in ('torch', 'ray', 'numpy', 'jsonschema', 'rich') if m in sys.modules); "
        "print(rc, heavy, [m for m in sys.modules if m.startswith('toysteps') and '.' in m])"
    )
    import subprocess

    out = subprocess.run(
        [sys.executable, "-c", code], env=toy.env(), capture_output=True, text=True, check=True
    )
    assert out.stdout.strip().splitlines()[-1] == "0 [] []"  # after the run's result lines


def test_packaged_example_scene_and_attribution():
    scene = example_scene_path()
    assert (scene / "ATTRIBUTION.txt").read_text().startswith('Sample scene "basket": attribution')
    assert (
        "CC BY 4.0" in (scene / "ATTRIBUTION.txt").read_text()
        or "CC-BY" in (scene / "ATTRIBUTION.txt").read_text()
    )
    frames = json.loads((scene / "transforms_train.json").read_text())["frames"]
    assert len(frames) == 4 and all(
        (scene / (f["file_path"].lstrip("./") + ".png")).is_file() for f in frames
    )


def test_validate_command(tmp_path, toy):
    """On the packaged example (no ../shared needed): what it holds; a missing image; no test split."""
    done = toy.cli("validate", str(example_scene_path()))
    assert done.returncode == 0, done.stderr
    assert "OK" in done.stdout and "train views : 4" in done.stdout
    assert "test views  : 8" in done.stdout and "transforms_train.json + transforms_test.json" in done.stdout
    broken = tmp_path / "broken"
    shutil.copytree(example_scene_path(), broken)
    (broken / "train" / "r_0.png").unlink()
    done = toy.cli("validate", str(broken))
    assert done.returncode == 2 and "r_0" in done.stderr and "image not found" in done.stderr
    no_test = tmp_path / "no_test"
    shutil.copytree(example_scene_path(), no_test)
    (no_test / "transforms_test.json").unlink()
    done = toy.cli("validate", str(no_test))
    assert done.returncode == 0, done.stderr
    assert "test views  : none (no test split" in done.stdout
    assert "split       : transforms_train.json\n" in done.stdout  # no test file named


@pytest.mark.slow
def test_run_example_end_to_end(tmp_path, toy):
    """`go-pipeline run --example` runs the real steps on the packaged scene (minutes on 2 cores)."""
    done = toy.cli("run", "--example", "--workdir", str(tmp_path / "ex"), timeout=3600)
    assert done.returncode == 0, done.stderr[-3000:]
    again = toy.cli("run", "--example", "--workdir", str(tmp_path / "ex"))
    assert again.returncode == 0 and "running" not in again.stderr
    # the work dir remembers the example profile: status and a plain run are up to date
    scene = tmp_path / "ex" / "basket"
    status = toy.cli("status", str(scene))
    assert status.stdout.splitlines()[-1] == "everything is up to date", status.stdout
    plain = toy.cli("run", str(scene))
    assert "everything is up to date" in plain.stderr and "running" not in plain.stderr
    # findable results: the model and its metrics, the paths, the next command
    assert "\nresult: the repair model" in "\n" + done.stdout and "test views: PSNR " in done.stdout
    # the repair model that ran: the one the tune step chose on the held-out folds (tune.prior_choice)
    (tune_json,) = (scene / ".go" / "artifacts" / "tune").glob("*/tune.json")
    chosen = json.loads(tune_json.read_text())["choice"]["chosen"]
    assert chosen in ("realesr-animevideov3-x4", "go-repair-prior-4")
    tuned = "fine-tuned" if chosen == "realesr-animevideov3-x4" else "pretrained (no fine-tuning)"
    assert f"compact:{chosen} ({tuned})" in done.stdout
    for name in (
        "model.ply",
        "model.glb",
        "model_mesh.ply",
        "turntable.gif",
        "camera_path.mp4",
        "metrics.json",
    ):
        assert (scene / ".go" / "outputs" / name).is_file(), name
    assert (scene / ".go" / "outputs" / "report.html").is_file()
    assert "next: " in plain.stdout


def test_example_scene_is_copied_once(tmp_path):
    import argparse

    from go_pipeline.commands.run import _example_scene

    args = argparse.Namespace(scene=None, workdir=str(tmp_path / "ex"))
    scene, _ = _example_scene(args)
    assert scene == tmp_path / "ex" / "basket"
    assert sorted(p.name for p in scene.iterdir()) == sorted(p.name for p in example_scene_path().iterdir())
    (scene / "marker").write_text("kept")
    assert _example_scene(args)[0] == scene and (scene / "marker").read_text() == "kept"
