"""The runner on a toy pipeline: cache keys, staleness, failures, locks, manifests, status and clean."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest
from _runner_toy import content_hashes, make_toy_project

from go_core.errors import GoError, SceneError
from go_pipeline import store
from go_pipeline.codehash import digest_of
from go_pipeline.commands.clean import clean
from go_pipeline.hashing import cache_key
from go_pipeline.lock import LockedError, WorkdirLock
from go_pipeline.manifest import schema_problems
from go_pipeline.runner import StepFailed, pipeline_status, run_pipeline

ALL = ["ingest", "double", "side", "train", "report"]


@pytest.fixture()
def toy(tmp_path):
    return make_toy_project(tmp_path)


def run(toy, **kw):
    kw.setdefault("quiet", True)
    return run_pipeline(toy.scene, pipeline_path=toy.pipeline, **kw)


def states(toy, **kw):
    return {r.step: (r.state, r.reason) for r in pipeline_status(toy.scene, pipeline_path=toy.pipeline, **kw)}


def test_first_run_then_noop(toy):
    first = run(toy)
    assert [s.name for s in first.steps] == ALL and first.ran == ALL
    for s in first.steps:
        m = store.load_manifest(s.artifact_dir)
        assert schema_problems("step_manifest", m) == []
        assert m["key"] == s.key and m["step"] == s.name and m["version"] == "1"
        assert set(m["outputs"]) == set(os.listdir(s.artifact_dir)) - {"manifest.json"}
        assert m["peak_mem_mb"] > 5 and m["wall_s"] > 0 and m["libraries"]["python"]
    assert store.load_manifest(first.step("ingest").artifact_dir)["record"] == {"count": 6}
    # the report's inputs name the upstream keys and content hashes
    rep = store.load_manifest(first.step("report").artifact_dir)
    assert rep["inputs"]["model"]["key"] == first.step("train").key
    assert json.loads((first.step("double").artifact_dir / "doubled.json").read_text())["numbers"] == [
        2.0,
        4.0,
        6.0,
        8.0,
        10.0,
        20.0,
    ]
    second = run(toy)
    assert second.ran == [] and [s.status for s in second.steps] == ["cached"] * 5
    assert [s.key for s in second.steps] == [s.key for s in first.steps]
    assert all(state == "fresh" for state, _ in states(toy).values())
    assert not list(toy.scene.glob(".go/checkpoints/*/*"))  # checkpoints removed after success
    assert (toy.scene / ".go" / "runs" / "last.json").is_file()
    log = first.log_path.read_text()
    assert "[ingest] read 6 numbers" in log and "[train] train: iterations 30/30 (100%)" in log


def test_cache_keys_stable_across_processes(toy, tmp_path):
    """Two fresh interpreters (different hash seeds, different scene paths) compute the same keys."""
    other = tmp_path / "elsewhere" / "scene_copy"
    shutil.copytree(toy.scene, other)
    keys = []
    for i, scene in enumerate([toy.scene, other]):
        env = toy.env() | {"PYTHONHASHSEED": str(17 + i)}
        code = (
            "import json,sys; from go_pipeline.runner import run_pipeline; "
            f"s=run_pipeline({str(scene)!r}, pipeline_path={str(toy.pipeline)!r}, quiet=True); "
            "print(json.dumps({x.name: x.key for x in s.steps}))"
        )
        out = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
        )
        keys.append(json.loads(out.stdout))
    assert keys[0] == keys[1] and len(set(keys[0].values())) == 5
    assert content_hashes(toy.scene / ".go") == content_hashes(other / ".go")
    # and the key is exactly sha256 of the documented material
    m = store.load_manifest(store.artifact_dir(toy.scene / ".go", "double"))
    inputs = {"data": m["inputs"]["data"]["content_hash"]}
    key = cache_key("double", "1", m["params"], 0, inputs, digest_of(m["code"]), m["function"], m["external"])
    assert key == m["key"]
    assert set(m["code"]) == {f"{toy.pkg}/__init__.py", f"{toy.pkg}/double.py"}


def test_param_change_makes_exactly_descendants_stale(toy):
    run(toy)
    st = states(toy, overrides={"double.factor": 3})
    assert st["ingest"][0] == st["side"][0] == "fresh"
    assert st["double"] == ("stale", "param factor changed 2.0 -> 3.0")
    assert st["train"] == ("stale", "upstream double is stale")
    assert st["report"] == ("stale", "upstream train is stale")
    summary = run(toy, overrides={"double.factor": 3})
    assert summary.ran == ["double", "train", "report"]
    # back to the defaults: everything is still cached (old artifacts are kept)
    assert run(toy).ran == []


def test_unused_param_change_stops_at_identical_output(toy):
    """train reruns for a new param value, but its output bytes are equal, so report stays cached."""
    base = run(toy)
    summary = run(toy, overrides={"train.extra": {"note": 1}})
    assert summary.ran == ["train"]
    assert summary.step("train").key != base.step("train").key
    assert summary.step("report").key == base.step("report").key


def test_scene_file_change_makes_all_scene_dependents_stale(toy):
    run(toy)
    (toy.scene / "b.txt").write_text("11\n")
    st = states(toy)
    assert st["ingest"] == ("stale", "scene folder 'folder' changed")
    assert {s for s, (state, _) in st.items() if state == "stale"} == set(ALL)
    assert run(toy).ran == ALL
    (toy.scene / "b.txt").write_text("10\n")  # restored content: the first artifacts are reused
    assert run(toy).ran == []
    (toy.scene / ".go" / "extra.txt").write_text("the work dir is not part of the scene")
    assert run(toy).ran == []


def test_version_change_makes_only_that_step_stale(toy):
    run(toy)
    toy.set_version("side", "2")
    st = states(toy)
    assert st["side"] == ("stale", f"version changed 1 -> 2; code changed: {toy.pkg}/side.py")
    assert [s for s, (state, _) in st.items() if state != "fresh"] == ["side"]
    assert run(toy).ran == ["side"]


def test_seed_is_part_of_every_key(toy):
    run(toy)
    st = states(toy, seed=1)
    assert st["ingest"] == ("stale", "seed changed 0 -> 1")
    summary = run(toy, seed=1)
    assert summary.ran == ALL


def test_force_until_and_profile(toy):
    summary = run(toy, until="double")
    assert [s.name for s in summary.steps] == ["ingest", "double"]
    assert states(toy)["train"] == ("missing", "never run")
    full = run(toy)
    assert full.ran == ["side", "train", "report"]
    forced = run(toy, force=["double"])
    assert forced.ran == ["double"]  # same output bytes: descendants stay cached
    quick = run(toy, profile="quick")
    assert quick.ran == ["train", "report"]
    assert store.load_manifest(quick.step("train").artifact_dir)["params"]["iterations"] == 10
    assert store.artifact_dir(toy.scene / ".go", "train") == quick.step("train").artifact_dir


def test_skipped_status(toy):
    summary = run(toy, overrides={"side": {"skip": True}})
    assert summary.step("side").status == "skipped"
    assert summary.step("side").record == {"status": "skipped", "reason": "label says skip"}
    assert run(toy, overrides={"side": {"skip": True}}).step("side").status == "skipped"


def test_step_crash_cleans_up_and_keeps_upstream(toy):
    with pytest.raises(StepFailed) as info:
        run(toy, overrides={"train.fail_at": 12})
    msg = str(info.value)
    assert msg.startswith("step 'train' failed: RuntimeError: boom at iteration 12; traceback in ")
    assert "Traceback" in open(msg.rsplit("traceback in ", 1)[1]).read()
    wd = toy.scene / ".go"
    assert not list(wd.glob("artifacts/*/.tmp-*"))
    assert not store.complete_artifacts(wd, "train")
    assert [p.name for p in wd.glob("checkpoints/train/*/ckpt-*.json")] == ["ckpt-000010.json"]
    assert run(toy, overrides={"train.fail_at": 12}, until="double").ran == []  # upstream is cached


def test_missing_output_fails_the_step(toy):
    with pytest.raises(StepFailed) as info:
        run(toy, overrides={"ingest.skip_output": True})
    assert str(info.value) == (
        f"{toy.step_file('ingest')}: step 'ingest' did not write its declared output(s): data.json"
    )
    assert not store.complete_artifacts(toy.scene / ".go", "ingest")
    assert not list((toy.scene / ".go").glob("artifacts/*/.tmp-*"))


def test_step_go_error_keeps_its_message(toy):
    for p in toy.scene.glob("*.txt"):
        p.unlink()
    (toy.scene / "notes.md").write_text("no numbers")
    with pytest.raises(SceneError) as info:
        run(toy)
    assert str(info.value) == f"{toy.scene}: no .txt files in the scene folder"


def test_in_process_mode_gives_identical_artifacts(toy, tmp_path):
    run(toy)
    summary = run_pipeline(
        toy.scene, pipeline_path=toy.pipeline, workdir=tmp_path / "w2", in_process=True, quiet=True
    )
    assert summary.ran == ALL
    assert content_hashes(tmp_path / "w2") == content_hashes(toy.scene / ".go")


def test_lock_stops_a_second_run(toy):
    wd = toy.scene / ".go"
    with WorkdirLock(wd):
        with pytest.raises(LockedError) as info:
            run(toy)
        assert str(info.value) == (
            f"{wd / 'lock'}: another `go-pipeline run` (pid {os.getpid()}) is using this "
            "work dir; wait for it to finish"
        )
        assert not (wd / "artifacts").exists()
        assert WorkdirLock(wd).holder() == str(os.getpid())  # what `status` reports
    assert WorkdirLock(wd).holder() is None
    assert run(toy).ran == ALL  # the lock is released


def test_clean_steps_and_old(toy):
    run(toy)
    run(toy, overrides={"double.factor": 3})
    wd = toy.scene / ".go"
    assert len(store.complete_artifacts(wd, "double")) == 2
    clean(wd, old=True)
    assert len(store.complete_artifacts(wd, "double")) == 1
    assert all(state == "fresh" for state, _ in states(toy, overrides={"double.factor": 3}).values())
    clean(wd, ["train"])
    st = states(toy, overrides={"double.factor": 3})
    assert st["train"] == ("missing", "never run")
    assert st["report"][0] == "stale" and "upstream train is missing" in st["report"][1]
    clean(wd)
    assert sorted(p.name for p in wd.iterdir()) == ["lock"]


def test_missing_scene_folder(tmp_path, toy):
    with pytest.raises(GoError) as info:
        run_pipeline(tmp_path / "nope", pipeline_path=toy.pipeline)
    assert str(info.value) == f"{tmp_path / 'nope'}: scene folder not found"


def test_unwritable_workdir_and_damaged_artifact(toy, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(GoError) as info:
        run(toy, workdir=blocker / "w")
    assert (
        str(info.value)
        == f"{blocker / 'w'}: cannot write the work dir (Not a directory); choose one with --workdir"
    )
    first = run(toy)
    (first.step("double").artifact_dir / "doubled.json").unlink()  # a damaged cache entry is rebuilt
    assert states(toy)["double"] == ("damaged", "doubled.json is missing")
    again = run(toy)
    assert again.ran == ["double"] and content_hashes(toy.scene / ".go") == {
        s.name: store.load_manifest(s.artifact_dir)["content_hash"] for s in first.steps
    }
