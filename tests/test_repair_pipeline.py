"""`run_pipeline` on the built-in example through eval with tiny random repair models, and without weights.

Slow (several minutes on a loaded 2-core machine: every step runs in its own process), hence marked slow.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests._tiny_repair import tiny_weights

EXAMPLE = Path(__file__).resolve().parents[1] / "go_pipeline" / "examples" / "basket"

# Small settings for every step (the values proposed for the `test` profile).
TEST_OVERRIDES = {
    "scene.max_size": 64,
    "coarse.iterations": 30,
    "coarse.densify_from": 10,
    "coarse.densify_until": 25,
    "coarse.densify_every": 10,
    "coarse.floater_from": 10,
    "coarse.floater_until": 20,
    "coarse.floater_every": 10,
    "coarse.checkpoint_every": 0,
    "loo.phase1_iterations": 15,
    "loo.phase2_iterations": 6,
    "loo.renders": 2,
    "loo.checkpoint_every": 0,
    "lora.rank": 4,
    "lora.alpha": 4.0,
    "lora.steps": 4,
    "lora.resolution": 64,
    "lora.checkpoint_every": 0,
    "repair.iterations": 8,
    "repair.repair_iterations": 6,
    "repair.refresh_every": 3,
    "repair.views_per_arc": 1,
    "repair.num_inference_steps": 10,
    "repair.resolution": 64,
    "repair.checkpoint_every": 0,
    "repair.densify_from": 2,
    "repair.densify_until": 6,
    "repair.densify_every": 2,
}


@pytest.mark.slow
def test_example_runs_through_eval_with_tiny_models_and_falls_back_without(tmp_path, monkeypatch):
    from go_pipeline.runner import run_pipeline

    for var in ("GO_SD15_PATH", "GO_CONTROLNET_TILE_PATH", "GO_CLIP_PATH", "GO_SD15_CONFIG"):
        monkeypatch.delenv(var, raising=False)
    weights = tiny_weights(tmp_path / "weights")
    work = tmp_path / "work"
    with_weights = {**TEST_OVERRIDES, **{f"weights.{k}": v for k, v in weights.items()}}
    summary = run_pipeline(EXAMPLE, workdir=work, overrides=with_weights, quiet=True)
    steps = {s.name: s for s in summary.steps}
    for name in ("loo", "noise_pairs", "lora", "repair", "eval"):
        assert steps[name].status == "ran", name
    assert steps["lora"].record["status"] == "ok" and steps["repair"].record["status"] == "ok"
    metrics = json.loads((steps["eval"].artifact_dir / "metrics.json").read_text())
    assert metrics["model"] == "repair"
    assert (steps["repair"].artifact_dir / "gaussians.npz").is_file()

    # Without weights: coarse is cached, the whole repair chain skips with the message, eval uses coarse.
    summary = run_pipeline(EXAMPLE, workdir=work, overrides=TEST_OVERRIDES, quiet=True)
    steps = {s.name: s for s in summary.steps}
    assert steps["coarse"].status == "cached"
    for name in ("loo", "noise_pairs", "lora"):
        assert steps[name].status == "skipped", name
    assert "Stable Diffusion 1.5" in steps["lora"].record["reason"]
    assert steps["repair"].status == "skipped"
    assert not (steps["repair"].artifact_dir / "gaussians.npz").exists()
    metrics = json.loads((steps["eval"].artifact_dir / "metrics.json").read_text())
    assert metrics["model"] == "coarse" and "Stable Diffusion 1.5" in metrics["model_reason"]
