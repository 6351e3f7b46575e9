"""Nothing on disk runs as code: planted pickles, a planted worker module in the current directory and a
pipeline file naming foreign functions (issue 21, "no code from data")."""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

import pytest
import torch
from _runner_toy import make_toy_project

from go_core.errors import PipelineError
from go_pipeline.runner import pipeline_status, run_pipeline


class _Canary:
    """Unpickling this runs ``open(path, 'w')``: what a hostile checkpoint would do with a shell command."""

    def __init__(self, path: Path) -> None:
        self.path = str(path)

    def __reduce__(self):
        return (open, (self.path, "w"))


def _plant(path: Path, canary: Path, payload_key: str = "format") -> None:
    """A torch-format file whose unpickling creates ``canary`` (torch.save pickles the object)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({payload_key: _Canary(canary)}, path)


def test_planted_pickle_is_not_executed_sanity(tmp_path):
    """The planted file does execute under a plain unpickler: the tests below would catch a regression."""
    canary = tmp_path / "canary"
    _plant(tmp_path / "x.pt", canary)
    torch.load(tmp_path / "x.pt", weights_only=False)
    assert canary.exists()


def test_planted_coarse_checkpoint_does_not_execute(tmp_path):
    from go_core.coarse.loop import CHECKPOINT
    from go_core.io.checkpoint import Checkpoints, CheckpointSpec

    canary = tmp_path / "canary"
    _plant(tmp_path / "ckpt" / "ckpt_9999999.pt", canary)
    assert Checkpoints(CheckpointSpec(tmp_path / "ckpt"), *CHECKPOINT).newest("0" * 16) is None
    assert not canary.exists()


def test_planted_lora_checkpoint_does_not_execute(tmp_path):
    from go_core.repair.tuning import _checkpoints

    canary = tmp_path / "canary"
    _plant(tmp_path / "ckpt" / "lora_step_9999999.pt", canary)
    assert _checkpoints(tmp_path / "ckpt", 1).newest("0" * 16) is None
    assert not canary.exists()


def test_planted_loo_rng_state_does_not_execute(tmp_path):
    from go_core.io.checkpoint import UnsafeCheckpoint, load_checkpoint

    canary = tmp_path / "canary"
    _plant(tmp_path / "rng_after_phase1.pt", canary)
    with pytest.raises(UnsafeCheckpoint, match="not a plain checkpoint"):
        load_checkpoint(tmp_path / "rng_after_phase1.pt")
    assert not canary.exists()


def test_plain_checkpoints_still_load(tmp_path):
    """What the steps save (tensors, an RNG state, optimizer state, nested dicts/lists, numpy RNG state
    with big ints) passes the weights-only loader."""
    import numpy as np

    from go_core.io.checkpoint import load_checkpoint

    p = torch.nn.Parameter(torch.ones(3))
    opt = torch.optim.Adam([p], lr=0.1)
    p.grad = torch.ones(3)
    opt.step()
    payload = {
        "format": 1,
        "rng": torch.Generator().manual_seed(3).get_state(),
        "optimizer": opt.state_dict(),
        "np_rng": np.random.default_rng(5).bit_generator.state,
        "order": [1, 2, 3],
        "stats": {"loss_log": [{"step": 1, "loss": 0.5}], "densify": {"clone": 2}},
    }
    torch.save(payload, tmp_path / "ok.pt")
    back = load_checkpoint(tmp_path / "ok.pt")
    assert torch.equal(back["rng"], payload["rng"])
    assert back["np_rng"] == payload["np_rng"]
    assert back["stats"] == payload["stats"]


def test_planted_worker_module_in_cwd_is_not_imported(tmp_path, monkeypatch):
    """`cd scene && go-pipeline run .` with a go_pipeline/worker.py in the scene folder runs ours."""
    toy = make_toy_project(tmp_path)
    canary = tmp_path / "canary"
    evil = toy.scene / "go_pipeline"
    evil.mkdir()
    (evil / "__init__.py").write_text("")
    (evil / "worker.py").write_text(f"open({str(canary)!r}, 'w').close()\n")
    monkeypatch.chdir(toy.scene)
    summary = run_pipeline(toy.scene, pipeline_path=toy.pipeline, until="ingest", quiet=True)
    assert summary.ran == ["ingest"]
    assert not canary.exists()


def test_custom_step_functions_need_the_explicit_flag(tmp_path, monkeypatch):
    monkeypatch.delenv("GO_ALLOW_CUSTOM_STEPS", raising=False)
    toy = make_toy_project(tmp_path)
    with pytest.raises(PipelineError, match="is not an installed step.*--allow-custom-steps"):
        run_pipeline(toy.scene, pipeline_path=toy.pipeline, quiet=True)
    with pytest.raises(PipelineError, match="a pipeline file is code"):
        pipeline_status(toy.scene, pipeline_path=toy.pipeline)
    assert not (toy.scene / ".go" / "artifacts").exists()
    done = toy.cli("run", str(toy.scene), "--pipeline", str(toy.pipeline), "--until", "ingest", "--quiet")
    assert done.returncode == 2 and "--allow-custom-steps" in done.stderr
    done = toy.cli(
        "run", str(toy.scene), "--pipeline", str(toy.pipeline), "--until", "ingest", "--allow-custom-steps"
    )
    assert done.returncode == 0, done.stderr
    summary = run_pipeline(toy.scene, pipeline_path=toy.pipeline, quiet=True, allow_custom_steps=True)
    assert "ingest" not in summary.ran


def test_function_is_part_of_the_key(tmp_path):
    """Another function with the same VERSION and params is another computation: not the cached artifact."""
    toy = make_toy_project(tmp_path)
    first = run_pipeline(toy.scene, pipeline_path=toy.pipeline, until="ingest", quiet=True)
    (toy.src / toy.pkg / "ingest2.py").write_text(toy.step_file("ingest").read_text())
    text = toy.pipeline.read_text().replace(f"{toy.pkg}.ingest:run", f"{toy.pkg}.ingest2:run")
    toy.pipeline.write_text(text)
    second = run_pipeline(toy.scene, pipeline_path=toy.pipeline, until="ingest", quiet=True)
    assert second.ran == ["ingest"]
    assert second.step("ingest").key != first.step("ingest").key


def test_signal_deaths_are_named():
    from go_pipeline.executor import death_message

    assert death_message(-signal.SIGKILL) == "the step process was killed by signal 9 (SIGKILL)"
    assert "out of memory" not in death_message(-signal.SIGKILL)
    assert death_message(-signal.SIGTERM).endswith("signal 15 (SIGTERM)")
    assert "out-of-memory killer" in death_message(-signal.SIGKILL, oom_killed=True)
    assert "exited with code 7" in death_message(7)


@pytest.mark.skipif(sys.platform != "linux", reason="signals to a child process")
def test_worker_killed_by_signal_is_reported_as_such(tmp_path):
    """A step process killed by SIGTERM: the error says so (not 'out of memory?')."""
    from go_pipeline.runner import StepFailed

    toy = make_toy_project(tmp_path)
    code = toy.step_file("double").read_text()
    toy.step_file("double").write_text(
        code.replace(
            "def run(ctx, inputs, params):\n",
            "def run(ctx, inputs, params):\n"
            "    import os, signal\n    os.kill(os.getpid(), signal.SIGTERM)\n",
        )
    )
    with pytest.raises(StepFailed, match=r"killed by signal 15 \(SIGTERM\)"):
        run_pipeline(toy.scene, pipeline_path=toy.pipeline, until="double", quiet=True)
    assert os.path.isdir(toy.scene / ".go")


# ------------------------------------------------------------------------------ verified artifacts
def _artifact(toy, step: str) -> Path:
    from go_pipeline import store

    found = store.artifact_dir(toy.scene / ".go", step)
    assert found is not None
    return found


def _states(toy, **kw) -> dict[str, str]:
    return {r.step: r.state for r in pipeline_status(toy.scene, pipeline_path=toy.pipeline, **kw)}


def test_truncated_artifact_is_damaged_and_recomputed(tmp_path):
    toy = make_toy_project(tmp_path)
    run_pipeline(toy.scene, pipeline_path=toy.pipeline, quiet=True)
    target = _artifact(toy, "double") / "doubled.json"
    good = target.read_bytes()
    target.write_bytes(good[: len(good) // 2])
    assert _states(toy)["double"] == "damaged"
    summary = run_pipeline(toy.scene, pipeline_path=toy.pipeline, quiet=True)
    assert summary.ran == ["double"]  # same bytes again: its consumers stay cached
    assert target.read_bytes() == good
    log = summary.log_path.read_text()
    assert "double       damaged" in log and "doubled.json has" in log and "Traceback" not in log


def test_bit_flipped_artifact_is_caught_before_a_consumer_reads_it(tmp_path):
    toy = make_toy_project(tmp_path)
    run_pipeline(toy.scene, pipeline_path=toy.pipeline, quiet=True)
    target = _artifact(toy, "double") / "doubled.json"
    good = target.read_bytes()
    flipped = bytearray(good)
    flipped[len(good) // 2] ^= 0x01
    target.write_bytes(bytes(flipped))
    assert _states(toy)["double"] == "fresh"  # sizes only
    assert _states(toy, verify=True)["double"] == "damaged"
    # a consumer about to read it (train, forced) gets it re-made first
    summary = run_pipeline(toy.scene, pipeline_path=toy.pipeline, quiet=True, force=("train",))
    assert sorted(summary.ran) == ["double", "train"]
    assert target.read_bytes() == good
    assert "recomputing before train reads it" in summary.log_path.read_text()
    # and `run --verify` catches it with no consumer running
    target.write_bytes(bytes(flipped))
    assert run_pipeline(toy.scene, pipeline_path=toy.pipeline, quiet=True).ran == []
    assert run_pipeline(toy.scene, pipeline_path=toy.pipeline, quiet=True, verify=True).ran == ["double"]
    assert target.read_bytes() == good


def test_broken_manifest_is_recomputed_without_a_traceback(tmp_path):
    toy = make_toy_project(tmp_path)
    run_pipeline(toy.scene, pipeline_path=toy.pipeline, quiet=True)
    manifest = _artifact(toy, "train") / "manifest.json"
    manifest.write_text(manifest.read_text()[:-40])  # no longer JSON
    status = toy.cli("status", str(toy.scene), "--pipeline", str(toy.pipeline))
    assert status.returncode == 0 and "Traceback" not in status.stderr, status.stderr
    assert "damaged" in status.stdout and "manifest.json unreadable" in status.stdout
    done = toy.cli("run", str(toy.scene), "--pipeline", str(toy.pipeline))
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    lines = [ln for ln in done.stderr.splitlines() if "damaged" in ln]
    assert len(lines) == 1 and "manifest.json unreadable" in lines[0]
    assert _states(toy)["train"] == "fresh"


# ------------------------------------------------------------------------------ every input in the key
def _example_copy(dest: Path) -> Path:
    import shutil

    from go_pipeline.resources import example_scene_path

    shutil.copytree(example_scene_path(), dest)
    return dest


def _scene_key(scene: Path, **kw) -> str:
    rows = pipeline_status(scene, **kw)
    return next(r.key for r in rows if r.step == "scene")


def _rewrite_same_size_and_mtime(path: Path) -> None:
    """Other bytes, the same size and timestamps (what a copied scene with one camera changed looks like)."""
    st = path.stat()
    data = bytearray(path.read_bytes())
    data[-1] ^= 0xFF
    path.write_bytes(bytes(data))
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))


def test_symlinked_image_edit_changes_the_key(tmp_path):
    import shutil

    scene = _example_copy(tmp_path / "scene")
    outside = tmp_path / "train_images"
    shutil.move(scene / "train", outside)
    (scene / "train").symlink_to(outside, target_is_directory=True)
    before = _scene_key(scene)
    image = sorted(outside.glob("*.png"))[0]
    _rewrite_same_size_and_mtime(image)
    assert _scene_key(scene) != before


def test_two_scenes_with_identical_sizes_and_mtimes_get_different_keys(tmp_path):
    import shutil

    first = _example_copy(tmp_path / "a")
    (first / ".go").mkdir()  # an existing work dir: status saves its hash cache there
    key_a = _scene_key(first)
    assert (first / ".go" / "cache" / "file_hashes.json").is_file()
    second = tmp_path / "b"
    shutil.copytree(first, second)  # with its .go/ hash cache, timestamps preserved
    _rewrite_same_size_and_mtime(sorted((second / "train").glob("*.png"))[0])
    assert _scene_key(second) != key_a
    assert _scene_key(first) == key_a


def test_files_named_outside_the_scene_folder(tmp_path):
    import json

    from go_core.errors import SceneError

    scene = _example_copy(tmp_path / "scene")
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    meta = json.loads((scene / "transforms_train.json").read_text())
    frame = meta["frames"][0]
    name = Path(frame["file_path"]).name + ".png"
    (scene / "train" / name).rename(outside / name)
    frame["file_path"] = f"../elsewhere/{Path(name).stem}"
    (scene / "transforms_train.json").write_text(json.dumps(meta))
    with pytest.raises(SceneError, match=r"outside its folder: .*elsewhere.*--allow-outside"):
        _scene_key(scene)
    before = _scene_key(scene, allow_outside=True)
    _rewrite_same_size_and_mtime(outside / name)
    assert _scene_key(scene, allow_outside=True) != before
    frame["file_path"] = str(outside / Path(name).stem)  # an absolute path
    (scene / "transforms_train.json").write_text(json.dumps(meta))
    with pytest.raises(SceneError, match="outside its folder"):
        _scene_key(scene)


def _step_key(scene: Path, step: str, **kw) -> str:
    return next(r.key for r in pipeline_status(scene, **kw) if r.step == step)


def test_model_files_given_by_path_are_in_the_key(tmp_path):
    scene = _example_copy(tmp_path / "scene")
    run_pipeline(scene, until="scene", quiet=True)  # mask and depth read only the ingested scene
    model = tmp_path / "model.onnx"
    model.write_bytes(b"first model")
    kw = {"overrides": {"mask.onnx_model": str(model)}}
    before = _step_key(scene, "mask", **kw)
    model.write_bytes(b"other model")  # the same path, other bytes
    assert _step_key(scene, "mask", **kw) != before
    folder = tmp_path / "depth_model"
    folder.mkdir()
    (folder / "config.json").write_text("{}")
    kw = {"overrides": {"depth.model_path": str(folder)}}
    before = _step_key(scene, "depth", **kw)
    (folder / "config.json").write_text('{"edited": 1}')
    assert _step_key(scene, "depth", **kw) != before


def test_lpips_weights_and_library_versions_are_in_the_key(tmp_path, monkeypatch):
    from go_pipeline.external import dependency_versions, external_inputs

    monkeypatch.setenv("GO_PIPELINE_CACHE", str(tmp_path / "cache"))
    params = {"lpips_nets": ["vgg", "alex"], "backend": "auto"}
    absent = external_inputs(params, None)
    assert absent["lpips_weights"] == {"alex": "absent", "vgg": "absent"}
    weights = tmp_path / "cache" / "lpips" / "vgg.safetensors"
    weights.parent.mkdir(parents=True)
    weights.write_bytes(b"weights v1")
    fetched = external_inputs(params, None)
    weights.write_bytes(b"weights v2")
    edited = external_inputs(params, None)
    assert fetched["lpips_weights"]["alex"] == "absent"
    assert len({d["lpips_weights"]["vgg"] for d in (absent, fetched, edited)}) == 3
    assert set(absent["libraries"]) == {"torch", "numpy", "pycolmap", "opencv-contrib-python-headless"}
    assert absent["libraries"]["torch"] == dependency_versions()["torch"] != "absent"
    assert "lpips_weights" not in external_inputs({"iterations": 3}, None)
    from go_core.io.weights_cache import lpips_weights_file
    from go_core.metrics.lpips_weights import weights_path

    assert lpips_weights_file("vgg") == weights_path("vgg") == weights
    # ... and the runner keys the eval step with them
    scene = _example_copy(tmp_path / "scene")
    run_pipeline(scene, until="scene", quiet=True)
    from go_pipeline.runner import _external, _plan

    plan = _plan(scene, None, None, None, 0, None)
    assert _external(plan, "eval")["lpips_weights"]["vgg"] == edited["lpips_weights"]["vgg"]


def test_a_workdir_is_bound_to_one_scene(tmp_path):
    from go_core.errors import GoError

    toy = make_toy_project(tmp_path)
    other = tmp_path / "other_scene"
    other.mkdir()
    (other / "a.txt").write_text("7\n")
    wd = tmp_path / "shared_wd"
    run_pipeline(toy.scene, workdir=wd, pipeline_path=toy.pipeline, until="ingest", quiet=True)
    with pytest.raises(GoError, match="holds the artifacts of another scene"):
        run_pipeline(other, workdir=wd, pipeline_path=toy.pipeline, until="ingest", quiet=True)
    with pytest.raises(GoError, match="holds the artifacts of another scene"):
        pipeline_status(other, workdir=wd, pipeline_path=toy.pipeline)
    # the scene's own .go/ stays bound by where it lives (a moved scene keeps its cache)
    moved = tmp_path / "moved"
    toy.scene.rename(moved)
    assert run_pipeline(moved, pipeline_path=toy.pipeline, until="ingest", quiet=True).ran == ["ingest"]
    assert run_pipeline(moved, pipeline_path=toy.pipeline, until="ingest", quiet=True).ran == []


# ------------------------------------------------------------------------------ smaller defects
def test_large_images_are_downscaled_by_default_with_a_warning(tmp_path):
    from go_pipeline.pipeline import load_pipeline
    from go_pipeline.store import load_manifest

    assert load_pipeline().steps["scene"].params["max_size"] == 1600  # the documented default
    scene = _example_copy(tmp_path / "scene")  # 160 px images: a max side of 100 stands for 1600
    summary = run_pipeline(scene, until="scene", overrides={"scene.max_size": 100}, quiet=True)
    log = summary.log_path.read_text()
    assert "images up to 160 px on their longest side were downscaled to 100 px" in log
    assert load_manifest(summary.step("scene").artifact_dir)["record"]["downscaled_from"] == 160
    kept = run_pipeline(scene, until="scene", overrides={"scene.max_size": 0}, quiet=True)
    assert "downscaled" not in kept.log_path.read_text()
