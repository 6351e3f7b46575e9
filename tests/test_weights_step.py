"""The `weights` step gates the repair chain: without weights nothing after coarse does real work."""

from __future__ import annotations

import json

import numpy as np
import pytest

from go_pipeline.pipeline import expand_env, load_pipeline
from tests._tiny_repair import run_weights_step, weights_artifact


def test_no_weights_configured_records_missing_with_how_to_get_them(tmp_path):
    out = run_weights_step(tmp_path, {})
    info = json.loads((out / "weights.json").read_text())
    assert info["status"] == "missing"
    assert "Stable Diffusion 1.5" in info["reason"] and "GO_SD15_PATH" in info["reason"]


def test_wrong_weight_path_is_an_error_not_a_skip(tmp_path):
    from go_core.errors import MissingWeightsError

    with pytest.raises(MissingWeightsError, match=str(tmp_path / "nowhere")):
        run_weights_step(tmp_path, {"sd15_path": str(tmp_path / "nowhere")})


def test_loo_and_noise_pairs_skip_without_reading_anything_else(tmp_path):
    """Without weights the runner skips loo and noise_pairs from their declarations (steps/registry.py):
    no worker, so nothing else is read; the skipped outputs are a skipped .json and an empty .npz."""
    from go_pipeline.steps.registry import STEPS

    from go_pipeline.skipping import cascade_skip, write_skipped_outputs

    record = json.loads((weights_artifact(tmp_path / "w", status="missing") / "weights.json").read_text())
    done = {"weights": {"record": {"status": "skipped", "reason": record["reason"]}}}
    for step in ("loo", "noise_pairs"):
        declared = STEPS[f"go_pipeline.steps.{step}"]
        skip = cascade_skip(declared.skip_if_skipped, {"weights": "weights"}, done)
        assert skip["status"] == "skipped" and "missing" in skip["reason"]
        write_skipped_outputs(tmp_path / step, tuple(a.file for a in declared.outputs), skip, step)
    assert json.loads((tmp_path / "loo" / "loo.json").read_text())["status"] == "skipped"
    with np.load(tmp_path / "loo" / "loo_pairs.npz") as pairs:
        assert len(pairs.files) == 0
    assert json.loads((tmp_path / "noise_pairs" / "noise_pairs.json").read_text())["status"] == "skipped"


def test_env_references_in_params_expand_like_the_shell():
    env = {"A": "/models/sd", "EMPTY": ""}
    assert expand_env("${A}/unet", env) == "/models/sd/unet"
    assert expand_env("${UNSET:-fallback}", env) == "fallback"
    assert expand_env("${EMPTY:-fallback}", env) == "fallback"
    assert expand_env("${UNSET}", env) == ""
    assert expand_env(5, env) == 5 and expand_env("plain $A", env) == "plain $A"


def test_weights_from_the_environment_are_part_of_the_resolved_params(monkeypatch):
    pipeline = load_pipeline()
    monkeypatch.delenv("GO_SD15_PATH", raising=False)
    assert pipeline.resolve_params()["weights"]["sd15_path"] == ""
    monkeypatch.setenv("GO_SD15_PATH", "/models/sd15")
    assert pipeline.resolve_params()["weights"]["sd15_path"] == "/models/sd15"


def test_loo_and_noise_pairs_skip_without_fine_tuning():
    """tune.finetune false: the leave-one-out runs only feed the tuning, so the runner skips them (a key of
    their own: the param is in it), and the noise pairs after them."""
    from go_pipeline.steps.registry import STEPS

    from go_pipeline.skipping import cascade_skip, foreign_param_skip, foreign_params

    loo = STEPS["go_pipeline.steps.loo"]
    assert foreign_param_skip(loo.skip_if_param, {"tune": {"finetune": True}}) is None
    skip = foreign_param_skip(loo.skip_if_param, {"tune": {"finetune": False}})
    assert skip["status"] == "skipped" and "tune.finetune false" in skip["reason"]
    assert foreign_params(loo.skip_if_param, {"tune": {"finetune": False}}) == {"tune.finetune": False}
    noise = STEPS["go_pipeline.steps.noise_pairs"]
    done = {"weights": {"record": {"status": "ok"}}, "loo": {"record": skip}}
    inputs = {"weights": "weights", "loo": "loo"}
    assert cascade_skip(noise.skip_if_skipped, inputs, done)["skip_root"] == "loo"
