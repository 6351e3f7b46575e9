"""Params that mean one thing (issue 82): the SD1.5 repair model's own settings are named ``sd15_*``, an old
plain name is one error naming the new one, and a ``--set`` that the run's repair model ignores is one
warning naming the param and why."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from go_pipeline.steps.registry import STEPS

from go_core.config import fields_of
from go_core.errors import PipelineError
from go_pipeline.pipeline import RENAMED_PARAMS, ignored_overrides, load_pipeline

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "go_pipeline" / "examples" / "basket"
SD15_ENV = ("GO_SD15_PATH", "GO_CONTROLNET_TILE_PATH", "GO_CLIP_PATH", "GO_SD15_CONFIG")


@pytest.fixture(autouse=True)
def _no_sd15_weights(monkeypatch):
    """The default path: auto, no SD1.5 weights configured, so the compact model repairs."""
    for var in SD15_ENV:
        monkeypatch.delenv(var, raising=False)


@pytest.fixture(scope="module")
def pipeline():
    return load_pipeline()


def _params_class(step: str) -> type:
    return STEPS[f"go_pipeline.steps.{step}"].params


@pytest.mark.parametrize(
    "step, old", [(step, old) for step, names in RENAMED_PARAMS.items() for old in names]
)
def test_an_old_name_is_one_error_naming_the_new_one(pipeline, step, old):
    new = RENAMED_PARAMS[step][old]
    fields = fields_of(_params_class(step))
    assert new in fields and old not in fields
    value = pipeline.resolve_params()[step][new]
    with pytest.raises(PipelineError) as info:
        pipeline.resolve_params(overrides={f"{step}.{old}": value})
    text = str(info.value)
    assert f": {step}.{old} is now called {step}.{new} (it acts only on the SD1.5 repair model): " in text
    assert text.endswith(f"write {step}.{new} instead of {step}.{old}") and "\n" not in text


def test_the_issue_check_tune_steps_on_a_default_run(tmp_path):
    """`go-pipeline run --set tune.steps=5` on a default-path run: not a silent no-op but one error line
    naming the new name, before anything is written."""
    cmd = [sys.executable, "-m", "go_pipeline.cli", "run", str(EXAMPLE), "--workdir", str(tmp_path / "w")]
    done = subprocess.run([*cmd, "--set", "tune.steps=5"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert lines == [
        "error: --set tune.steps=5: tune.steps is now called tune.sd15_steps (it acts only on the SD1.5 "
        "repair model): write tune.sd15_steps instead of tune.steps"
    ]
    assert not (tmp_path / "w" / "artifacts").exists()


def _with(tmp_path: Path, old: str, new: str) -> Path:
    text = (REPO / "pipeline.yaml").read_text(encoding="utf-8")
    assert text.count(old) == 1
    path = tmp_path / "pipeline.yaml"
    path.write_text(text.replace(old, new), encoding="utf-8")
    return path


def test_an_old_name_in_a_profile_or_in_pipeline_yaml_is_one_error(tmp_path):
    profile = _with(tmp_path, "  fast:", "  old:\n    repair: {num_inference_steps: 5}\n  fast:")
    with pytest.raises(PipelineError, match=r"profile 'old': repair.num_inference_steps is now called "):
        load_pipeline(profile)
    step = "    function: go_pipeline.steps.tune:run\n"
    yaml = _with(tmp_path, step, step + "    params: {lr: 0.01}\n")
    with pytest.raises(
        PipelineError, match=r"step 'tune': param 'lr' is now called 'sd15_lr': write sd15_lr"
    ):
        load_pipeline(yaml)


def test_a_set_the_compact_model_ignores_is_one_warning(pipeline):
    sets = {"tune.sd15_steps": 5, "tune.compact_steps": 7, "repair.sd15_eta": 0.5, "coarse.iterations": 3}
    lines = ignored_overrides(pipeline, pipeline.resolve_params(overrides=sets), sets)
    tail = "is ignored: it acts only on the SD1.5 repair model, and this run repairs with the compact model"
    assert lines == [
        f"warning: --set tune.sd15_steps=5 {tail} (weights.repair_model auto, no SD1.5 weights configured)",
        f"warning: --set repair.sd15_eta=0.5 {tail} (weights.repair_model auto, no SD1.5 weights configured)",
    ]


def test_with_sd15_the_compact_params_are_the_ignored_ones(pipeline, monkeypatch):
    sets = {"tune.sd15_steps": 5, "repair.compact_lpips": 0.5}
    named = {**sets, "weights.repair_model": "sd15"}
    lines = ignored_overrides(pipeline, pipeline.resolve_params(overrides=named), sets)
    assert lines == [
        "warning: --set repair.compact_lpips=0.5 is ignored: it acts only on the compact repair model, and "
        "this run repairs with the SD1.5 model (weights.repair_model sd15)"
    ]
    monkeypatch.setenv("GO_SD15_PATH", "/models/sd15")  # auto with a path given: sd15 (or an error)
    lines = ignored_overrides(pipeline, pipeline.resolve_params(overrides=sets), sets)
    assert [line.split(" is ignored")[0] for line in lines] == ["warning: --set repair.compact_lpips=0.5"]
    assert lines[0].endswith("(weights.repair_model auto, SD1.5 weights configured)")


def test_profile_values_are_not_warned_about(pipeline):
    """The example and test profiles set both models' values on purpose: only --set values warn."""
    for profile in ("example", "test"):
        assert ignored_overrides(pipeline, pipeline.resolve_params(profile), {}) == []


def test_a_run_prints_the_warning_once(tmp_path, capsys):
    from go_pipeline.runner import run_pipeline

    work = tmp_path / "work"
    run_pipeline(EXAMPLE, workdir=work, overrides={"tune.sd15_steps": 5}, until="scene", in_process=True)
    err = capsys.readouterr().err
    assert err.count("warning: --set tune.sd15_steps=5 is ignored: ") == 1, err
    log = next((work / "logs").glob("*.log")).read_text(encoding="utf-8")
    assert "warning: --set tune.sd15_steps=5 is ignored" in log
