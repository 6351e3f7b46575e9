"""`run_pipeline` on the built-in example through eval with tiny random repair models, and without weights.

Slow (several minutes on a loaded 2-core machine: every step runs in its own process), hence marked slow.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests._tiny_repair import tiny_weights

EXAMPLE = Path(__file__).resolve().parents[1] / "go_pipeline" / "examples" / "basket"


@pytest.mark.slow
def test_example_runs_through_eval_with_tiny_models_and_falls_back_without(tmp_path, monkeypatch):
    from go_pipeline.runner import run_pipeline

    for var in ("GO_SD15_PATH", "GO_CONTROLNET_TILE_PATH", "GO_CLIP_PATH", "GO_SD15_CONFIG"):
        monkeypatch.delenv(var, raising=False)
    weights = tiny_weights(tmp_path / "weights")
    work = tmp_path / "work"
    with_weights = {f"weights.{k}": v for k, v in weights.items()}
    with_weights["weights.repair_model"] = "sd15"
    summary = run_pipeline(EXAMPLE, workdir=work, profile="test", overrides=with_weights, quiet=True)
    steps = {s.name: s for s in summary.steps}
    for name in ("loo", "noise_pairs", "tune", "repair", "eval"):
        assert steps[name].status == "ran", name
    assert steps["tune"].record["status"] == "ok" and steps["repair"].record["status"] == "ok"
    metrics = json.loads((steps["eval"].artifact_dir / "metrics.json").read_text())
    assert metrics["model"] == "repair"
    assert (steps["repair"].artifact_dir / "gaussians.npz").is_file()

    # sd15 chosen without its weights: coarse is cached, the whole repair chain skips with the message, eval
    # uses coarse. (weights.repair_model auto would choose the compact model instead.)
    summary = run_pipeline(
        EXAMPLE, workdir=work, profile="test", overrides={"weights.repair_model": "sd15"}, quiet=True
    )
    steps = {s.name: s for s in summary.steps}
    assert steps["coarse"].status == "cached"
    assert "Stable Diffusion 1.5" in steps["weights"].record["reason"]  # the long message: once
    for name in ("loo", "noise_pairs", "tune", "repair"):  # skipped by the runner, without a worker
        assert steps[name].status == "skipped", name
        assert steps[name].record["reason"] == "repair model weights missing (see the weights step)", name
    assert not (steps["repair"].artifact_dir / "gaussians.npz").exists()
    metrics = json.loads((steps["eval"].artifact_dir / "metrics.json").read_text())
    assert metrics["model"] == "coarse" and "repair model weights missing" in metrics["model_reason"]


@pytest.mark.slow
def test_example_runs_the_compact_repair_chain_by_default(tmp_path, monkeypatch):
    """weights.repair_model auto without SD weights: the compact model runs loo → repair and eval says so."""
    from go_core.compact.weights import DEFAULT_MODEL, compact_path
    from go_pipeline.runner import run_pipeline

    if not compact_path(DEFAULT_MODEL).is_file():
        pytest.skip(f"{compact_path(DEFAULT_MODEL)} missing: run `go-pipeline weights fetch`")
    for var in ("GO_SD15_PATH", "GO_CONTROLNET_TILE_PATH", "GO_CLIP_PATH", "GO_SD15_CONFIG"):
        monkeypatch.delenv(var, raising=False)
    summary = run_pipeline(EXAMPLE, workdir=tmp_path / "work", profile="test", quiet=True)
    steps = {s.name: s for s in summary.steps}
    for name in ("loo", "noise_pairs", "tune", "repair", "eval"):
        assert steps[name].status == "ran", name
    assert steps["repair"].record["repair_model"] == "compact"
    metrics = json.loads((steps["eval"].artifact_dir / "metrics.json").read_text())
    choice = json.loads((steps["tune"].artifact_dir / "tune.json").read_text())["choice"]
    assert choice["tuned"] == DEFAULT_MODEL and choice["prior"] == "go-repair-prior-4"  # tune.prior_choice
    assert metrics["model"] == "repair" and metrics["repair_model"].startswith(f"compact:{choice['chosen']}")

    # another compact model: the leave-one-out runs and noise pairs do not read the weights (only whether
    # there are any: a gate input), so they stay cached; the chain from tune on runs with the new model
    prior = {"weights.compact_model": "go-repair-prior-1-noref"}
    summary = run_pipeline(EXAMPLE, workdir=tmp_path / "work", profile="test", overrides=prior, quiet=True)
    steps = {s.name: s for s in summary.steps}
    assert steps["loo"].status == "cached" and steps["noise_pairs"].status == "cached"
    assert steps["weights"].status == "ran" and steps["tune"].record["status"] == "ok"
    assert steps["repair"].record["status"] == "ok"

    # no fine-tuning: the tuning pairs are not made (the runner skips loo and noise_pairs), the pretrained
    # model repairs
    untuned = {**prior, "tune.finetune": False}
    summary = run_pipeline(EXAMPLE, workdir=tmp_path / "work", profile="test", overrides=untuned, quiet=True)
    steps = {s.name: s for s in summary.steps}
    assert steps["loo"].status == "skipped" and steps["noise_pairs"].status == "skipped"
    assert "tune.finetune false" in steps["loo"].record["reason"]
    assert steps["tune"].record["status"] == "pretrained" and steps["repair"].record["status"] == "ok"

    # the "no repair" ablation runs none of the repair chain: the runner skips it from its root, no worker
    summary = run_pipeline(
        EXAMPLE, workdir=tmp_path / "work", profile="test", overrides={"repair.mode": "no_repair"}, quiet=True
    )
    steps = {s.name: s for s in summary.steps}
    assert steps["coarse"].status == "cached"
    for name in ("weights", "loo", "noise_pairs", "tune", "repair"):
        assert steps[name].status == "skipped", name
        assert steps[name].record["worker"] == "none (skipped by the runner)", name
    metrics = json.loads((steps["eval"].artifact_dir / "metrics.json").read_text())
    assert metrics["model"] == "coarse" and "repair.mode no_repair" in metrics["model_reason"]


@pytest.mark.slow
def test_refined_poses_flow_through_the_chain_and_eval_scores_them_as_cf(tmp_path, monkeypatch):
    """coarse.refine_poses: coarse writes the refined cameras, the repair chain renders at them, and eval
    aligns the test cameras (similarity + per-view fit) and marks its metrics as CF metrics."""
    from go_core.compact.weights import DEFAULT_MODEL, compact_path
    from go_pipeline.runner import run_pipeline

    if not compact_path(DEFAULT_MODEL).is_file():
        pytest.skip(f"{compact_path(DEFAULT_MODEL)} missing: run `go-pipeline weights fetch`")
    for var in ("GO_SD15_PATH", "GO_CONTROLNET_TILE_PATH", "GO_CLIP_PATH", "GO_SD15_CONFIG"):
        monkeypatch.delenv(var, raising=False)
    overrides = {"coarse.refine_poses": True, "coarse.pose_refine_from": 0, "eval.test_pose_iterations": 5}
    work = tmp_path / "work"
    summary = run_pipeline(EXAMPLE, workdir=work, profile="test", overrides=overrides, quiet=True)
    steps = {s.name: s for s in summary.steps}
    for name in ("coarse", "loo", "noise_pairs", "tune", "repair", "eval"):
        assert steps[name].status == "ran", name
    cameras = json.loads((steps["coarse"].artifact_dir / "cameras.json").read_text())
    assert cameras["refined"] and cameras["cameras"][0]["rotation_change_deg"] == 0.0  # the gauge
    assert any(c["rotation_change_deg"] > 0 for c in cameras["cameras"][1:])
    metrics = json.loads((steps["eval"].artifact_dir / "metrics.json").read_text())
    assert metrics["poses"]["cf"] is True and "similarity" in metrics["poses"]["test"]
    assert metrics["model"] == "repair"
