"""noise_pairs → tune → repair steps end to end with tiny random models; honest skips without weights."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from go_pipeline.pipeline import step_params
from tests._tiny_repair import (
    WEIGHT_KEYS,
    FakeCtx,
    one_thread,
    run_weights_step,
    synthetic_inputs,
    tiny_weights,
)

LOO = {"phase1_iterations": 12, "phase2_iterations": 6, "renders": 2, "checkpoint_every": 0}
LORA = {"sd15_rank": 4, "sd15_alpha": 4.0, "sd15_steps": 6, "sd15_resolution": 64, "checkpoint_every": 2}
REPAIR = {
    "iterations": 10,
    "repair_iterations": 8,
    "refresh_every": 4,
    "views_per_arc": 2,
    "sd15_num_inference_steps": 10,
    "sd15_resolution": 64,
    "checkpoint_every": 5,
    "sd15_lpips": 0.0,
    "coarse": {"iterations": 20, "checkpoint_every": 8},  # the consensus's second coarse fit
}


@pytest.fixture(autouse=True)
def _threads(monkeypatch):
    for var in ("GO_SD15_PATH", "GO_CONTROLNET_TILE_PATH", "GO_CLIP_PATH", "GO_SD15_CONFIG"):
        monkeypatch.delenv(var, raising=False)
    with one_thread():
        yield


@pytest.fixture(scope="module")
def upstream(tmp_path_factory):
    """Inputs, loo and noise_pairs artifacts, and tiny weights."""
    from go_pipeline.steps import loo, noise_pairs

    root = tmp_path_factory.mktemp("repair_steps")
    with one_thread():
        dirs = synthetic_inputs(root)
        ctx = FakeCtx(root, "loo")
        loo.run(ctx, dirs, step_params(loo.__name__, LOO))
        dirs["loo"] = ctx.out_dir
        ctx = FakeCtx(root, "noise_pairs")
        noise_pairs.run(ctx, dirs, step_params(noise_pairs.__name__, {"preview_size": 32}))
        dirs["noise_pairs"] = ctx.out_dir
        weights = tiny_weights(root / "weights")
    return root, dirs, weights


def _tune(root, dirs, params, name="tune"):
    """The weights step on the weight paths in ``params``, then the tune step on the rest."""
    from go_pipeline.steps import tune

    weights = run_weights_step(root / f"{name}_weights", params)
    ctx = FakeCtx(root, name)
    tune.run(
        ctx,
        {**dirs, "weights": weights},
        step_params(tune.__name__, {k: v for k, v in params.items() if k not in WEIGHT_KEYS}),
    )
    return ctx


def test_noise_pairs_step_fixes_config(upstream):
    _, dirs, _ = upstream
    cfg = json.loads((dirs["noise_pairs"] / "noise_pairs.json").read_text())
    loo = json.loads((dirs["loo"] / "loo.json").read_text())
    assert cfg["stats"] == loo["stats"] and cfg["p0"] == 1.0 and cfg["decay"] == 0.995
    assert cfg["attributes"] == ["means", "log_scales", "quats", "opacity_logits"]
    assert (dirs["noise_pairs"] / "preview.png").is_file()


def test_without_weights_the_runner_skips_tune_and_repair(upstream, tmp_path):
    """sd15 chosen without its weights: the weights step says why, in full, once; the runner then skips tune
    and repair without a worker (their declarations in steps/registry.py), and the final model is coarse."""
    from go_pipeline.steps.registry import STEPS

    from go_core import artifacts
    from go_pipeline.skipping import cascade_skip, write_skipped_outputs

    _, dirs, _ = upstream
    wctx_dir = run_weights_step(tmp_path / "w", {})
    winfo = json.loads((wctx_dir / "weights.json").read_text())
    assert winfo["status"] == "missing" and "Stable Diffusion 1.5" in winfo["reason"]
    assert "GO_SD15_PATH" in winfo["reason"]
    done = {"weights": {"record": {"status": "skipped", "reason": winfo["reason"]}}}
    for step, upstream_input in (("tune", "weights"), ("repair", "tune")):
        declared = STEPS[f"go_pipeline.steps.{step}"]
        record = cascade_skip(declared.skip_if_skipped, {upstream_input: upstream_input}, done)
        assert record["status"] == "skipped"
        assert record["reason"] == "repair model weights missing (see the weights step)"
        out = tmp_path / step
        write_skipped_outputs(out, tuple(a.file for a in declared.outputs), record, step)
        assert sorted(p.name for p in out.iterdir()) == [declared.outputs[0].file]
        done[step] = {"record": record}
    folder, used, _ = artifacts.final_model(dirs["coarse"], tmp_path / "repair")
    assert used == "coarse" and folder == dirs["coarse"]


def test_configured_but_wrong_weights_raise_one_clear_error(upstream, tmp_path):
    from go_core.errors import MissingWeightsError

    _, dirs, weights = upstream
    with pytest.raises(MissingWeightsError) as err:
        _tune(tmp_path, dirs, {**weights, "controlnet_path": str(tmp_path / "typo")})
    assert str(tmp_path / "typo") in str(err.value) and "control_v11f1e_sd15_tile" in str(err.value)
    assert "\n" not in str(err.value)


def test_killed_lora_step_resumes_from_last_checkpoint(upstream, tmp_path, monkeypatch):
    from go_core.diffusion.lora import read_lora
    from go_core.io.checkpoint import Checkpoints

    root, dirs, weights = upstream
    params = {**weights, **LORA}
    full = _tune(tmp_path / "a", dirs, params)
    saved = []
    original = Checkpoints.save

    def save_then_die(self, step, fingerprint, payload):
        original(self, step, fingerprint, payload)
        saved.append(step)
        if step == 4:
            raise KeyboardInterrupt("simulated kill after the step-4 checkpoint")

    monkeypatch.setattr(Checkpoints, "save", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        _tune(tmp_path / "b", dirs, params)
    assert saved == [2, 4]
    monkeypatch.setattr(Checkpoints, "save", original)
    resumed = _tune(tmp_path / "b", dirs, params)
    assert resumed.records["resumed_from"] == 4 and full.records["resumed_from"] == 0
    _, a = read_lora(full.out_dir / "lora.safetensors")
    _, b = read_lora(resumed.out_dir / "lora.safetensors")
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert (full.out_dir / "tune.json").read_bytes() == (resumed.out_dir / "tune.json").read_bytes()
    info = json.loads((full.out_dir / "tune.json").read_text())
    assert info["status"] == "ok" and info["pairs_used"]["noise"] + info["pairs_used"]["loo"] == 6
    assert any(float(v.abs().max()) > 0 for k, v in a.items() if "lora_B" in k)  # LoRA moved from zero


def test_repair_end_to_end_views_on_arcs_and_formulas(upstream, tmp_path):
    from go_pipeline.steps import repair

    from go_core import artifacts
    from go_core.diffusion.configs import SD15_SCHEDULER
    from go_core.repair.arcs import RepairArcs
    from go_core.scene.artifact import load_scene_artifact

    _, dirs, weights = upstream
    lctx = _tune(tmp_path, dirs, {**weights, **LORA, "checkpoint_every": 0})
    ctx = FakeCtx(tmp_path, "repair")
    repair.run(ctx, {**dirs, "tune": lctx.out_dir}, step_params(repair.__name__, REPAIR))
    info = json.loads((ctx.out_dir / "repair.json").read_text())
    assert info["status"] == "ok" and info["lora"] == "fine-tuned" and info["lpips_term"] == "off (weight 0)"
    assert info["refreshes"] == 2 and ctx.records["refreshes_made"] == 2
    folder, used, _ = artifacts.final_model(dirs["coarse"], ctx.out_dir)
    assert used == "repair" and artifacts.GAUSSIANS.path(folder).is_file()

    scene = load_scene_artifact(dirs["scene"])
    arcs = RepairArcs.from_cameras(scene.train_cameras, keep=0.8)
    test_centres = np.stack([c.center for c in scene.test_cameras])
    refs = np.stack([c.center for c in arcs.references])
    d = np.linalg.norm(refs - np.roll(refs, -1, axis=0), axis=1).max()
    betas = np.linspace(np.sqrt(SD15_SCHEDULER["beta_start"]), np.sqrt(SD15_SCHEDULER["beta_end"]), 1000) ** 2
    alpha_bar = np.cumprod(1 - betas)
    files = sorted((ctx.checkpoint_dir / "refresh").glob("refresh_*.pt"))
    assert len(files) == 2
    for f in files:
        views = torch.load(f, weights_only=False)
        assert len(views) == 4 * 2  # two per repair path
        for v in views:
            w2c = np.array(v["camera"]["world_to_cam"])
            centre = -w2c[:3, :3].T @ w2c[:3, 3]
            theta = float(arcs.ellipse.angle_of(centre)[0])
            arc, frac = arcs.arc_position(theta)
            assert arc == v["arc"] and 0.1 - 1e-9 <= frac <= 0.9 + 1e-9
            assert np.linalg.norm(arcs.ellipse.point(theta) - centre) < 1e-6
            assert np.linalg.norm(test_centres - centre, axis=1).min() > 1e-3  # never a test camera
            assert v["lam"] == pytest.approx(2 * np.linalg.norm(refs - centre, axis=1).min() / d)
            assert v["w"] == pytest.approx(1 - alpha_bar[v["timestep"]], rel=1e-5)
            assert (v["timestep"] - 1) % 100 == 0  # a DDIM timestep of the 10-step schedule (901 ... 1)
    assert (ctx.out_dir / "repair_preview.png").is_file()


def test_ablations_no_finetune_and_no_repair(upstream, tmp_path):
    from go_pipeline.steps import repair

    _, dirs, weights = upstream
    lctx = _tune(tmp_path, dirs, {**weights, **LORA, "finetune": False})
    linfo = json.loads((lctx.out_dir / "tune.json").read_text())
    assert linfo["status"] == "pretrained" and not (lctx.out_dir / "lora.safetensors").exists()
    ctx = FakeCtx(tmp_path, "repair")
    repair.run(
        ctx,
        {**dirs, "tune": lctx.out_dir},
        step_params(repair.__name__, {**REPAIR, "iterations": 3, "repair_iterations": 2}),
    )
    assert json.loads((ctx.out_dir / "repair.json").read_text())["lora"] == "pretrained (no fine-tuning)"
    ctx = FakeCtx(tmp_path, "repair_sds")
    repair.run(
        ctx,
        {**dirs, "tune": lctx.out_dir},
        step_params(repair.__name__, {**REPAIR, "iterations": 3, "repair_iterations": 2, "loss": "sds"}),
    )
    assert json.loads((ctx.out_dir / "repair.json").read_text())["loss"] == "sds"
    ctx = FakeCtx(tmp_path, "repair_none")
    repair.run(
        ctx, {**dirs, "tune": lctx.out_dir}, step_params(repair.__name__, {**REPAIR, "mode": "no_repair"})
    )
    info = json.loads((ctx.out_dir / "repair.json").read_text())
    assert info["status"] == "skipped" and "no repair" in info["reason"]
    assert not (ctx.out_dir / "gaussians.npz").exists()


class _Killed(RuntimeError):
    pass


def _gaussians_bytes(folder) -> bytes:
    return (folder / "gaussians.npz").read_bytes()


def test_consensus_second_model_is_the_library_chain_at_a_derived_seed(upstream, tmp_path):
    """repair.consensus: the second model is fit_coarse + repair_gaussians at derive_seed(seed, "consensus")
    (recomputed here from the library functions), and the repaired model differs from the plain repair."""
    from go_pipeline.steps import repair

    from go_core import artifacts as art
    from go_core.coarse.fit import coarse_inputs, fit_coarse
    from go_core.errors import GoError
    from go_core.seeding import derive_seed

    _, dirs, weights = upstream
    tune_dir = _tune(tmp_path, dirs, {**weights, **LORA, "checkpoint_every": 0}).out_dir
    ctx = FakeCtx(tmp_path, "repair")
    params = step_params(repair.__name__, REPAIR)
    repair.run(ctx, {**dirs, "tune": tune_dir}, params)
    info = json.loads((ctx.out_dir / "repair.json").read_text())
    seed_b = derive_seed(0, "consensus")
    assert info["consensus"]["seed"] == seed_b != 0

    fitted, _, _ = fit_coarse(
        coarse_inputs(dirs["scene"], dirs["mask"], dirs["hull"]), params.coarse.scaled_schedule(), seed_b
    )
    phase = ctx.checkpoint_dir / "consensus"
    assert torch.equal(art.read_gaussians(phase / "coarse").means, fitted.means)
    assert info["consensus"]["coarse_gaussians"] == len(fitted)
    assert info["consensus"]["gaussians"] == len(art.read_gaussians(phase / "repaired"))

    plain = FakeCtx(tmp_path, "repair_plain")
    repair.run(
        plain, {**dirs, "tune": tune_dir}, step_params(repair.__name__, {**REPAIR, "consensus": False})
    )
    assert json.loads((plain.out_dir / "repair.json").read_text())["consensus"] == "off"
    assert not (plain.checkpoint_dir / "consensus").exists()
    ours, theirs = art.read_gaussians(ctx.out_dir), art.read_gaussians(plain.out_dir)
    assert len(ours) != len(theirs) or not torch.equal(ours.means, theirs.means)

    coarse_only = FakeCtx(tmp_path, "repair_coarse_member")
    repair.run(
        coarse_only,
        {**dirs, "tune": tune_dir},
        step_params(repair.__name__, {**REPAIR, "consensus_member": "coarse"}),
    )
    member = json.loads((coarse_only.out_dir / "repair.json").read_text())["consensus"]
    assert member == {**info["consensus"], "member": "coarse", "gaussians": len(fitted)}
    assert not (coarse_only.checkpoint_dir / "consensus" / "repaired").exists()
    other = art.read_gaussians(coarse_only.out_dir)
    assert len(other) != len(ours) or not torch.equal(other.means, ours.means)

    with pytest.raises(GoError, match="consensus_restorer.*compact"):  # a compact model for an sd15 run
        repair.run(
            FakeCtx(tmp_path, "repair_prior_member"),
            {**dirs, "tune": tune_dir},
            step_params(repair.__name__, {**REPAIR, "consensus_restorer": "go-repair-prior-4"}),
        )


def test_consensus_of_three_models_adds_a_third_at_its_own_seed(upstream, tmp_path):
    """repair.consensus_models 3: the second model is the one of two models (same seed, same Gaussians), the
    third is fit_coarse at derive_seed(seed, "consensus-3") under ``consensus-3/``, both are recorded, and
    the result differs from the two models' repair."""
    from go_pipeline.steps import repair

    from go_core import artifacts as art
    from go_core.coarse.fit import coarse_inputs, fit_coarse
    from go_core.seeding import derive_seed

    _, dirs, weights = upstream
    tune_dir = _tune(tmp_path, dirs, {**weights, **LORA, "checkpoint_every": 0}).out_dir
    runs = {}
    for n in (2, 3):
        ctx = FakeCtx(tmp_path, f"repair_{n}")
        repair.run(
            ctx, {**dirs, "tune": tune_dir}, step_params(repair.__name__, {**REPAIR, "consensus_models": n})
        )
        runs[n] = (ctx, json.loads((ctx.out_dir / "repair.json").read_text())["consensus"])
    (two, record_2), (three, record_3) = runs[2], runs[3]
    assert record_2["models"] == 2 and "further" not in record_2
    assert record_3["models"] == 3 and {k: record_3[k] for k in record_2 if k != "models"} == {
        k: v for k, v in record_2.items() if k != "models"
    }
    seed_c = derive_seed(0, "consensus-3")
    assert record_3["further"][0]["seed"] == seed_c not in (0, record_2["seed"])
    for phase in ("coarse", "repaired"):
        assert _gaussians_bytes(three.checkpoint_dir / "consensus" / phase) == _gaussians_bytes(
            two.checkpoint_dir / "consensus" / phase
        )
    params = step_params(repair.__name__, REPAIR)
    fitted, _, _ = fit_coarse(
        coarse_inputs(dirs["scene"], dirs["mask"], dirs["hull"]), params.coarse.scaled_schedule(), seed_c
    )
    third = three.checkpoint_dir / "consensus-3"
    assert torch.equal(art.read_gaussians(third / "coarse").means, fitted.means)
    assert record_3["further"][0]["gaussians"] == len(art.read_gaussians(third / "repaired"))
    assert _gaussians_bytes(three.out_dir) != _gaussians_bytes(two.out_dir)


def test_repair_views_are_the_training_views_at_the_coarse_models_cameras(upstream, tmp_path):
    """The repair step reads the scene once (the coarse stage's inputs) for its views and the second model's
    fit: those views equal training_views' (the same images, masks and fitted cameras, no depth), and a
    coarse model fitted at moved cameras (its cameras.json) moves them."""
    import shutil
    from dataclasses import replace

    from go_core import artifacts as art
    from go_core.coarse.fit import coarse_inputs
    from go_core.repair.data import repair_views, training_views

    _, dirs, _ = upstream
    ours = repair_views(coarse_inputs(dirs["scene"], dirs["mask"], dirs["hull"]).views, dirs["coarse"])
    _, theirs = training_views(dirs["scene"], dirs["mask"], dirs["coarse"])
    assert len(ours) == len(theirs) > 0
    for a, b in zip(ours, theirs, strict=True):
        assert a.depth is None and b.depth is None
        assert torch.equal(a.image, b.image) and torch.equal(a.mask, b.mask)
        assert a.camera.name == b.camera.name
        assert np.array_equal(a.camera.K, b.camera.K)
        assert np.array_equal(a.camera.world_to_cam, b.camera.world_to_cam)

    moved_dir = tmp_path / "coarse_moved"
    shutil.copytree(dirs["coarse"], moved_dir)
    moved = [replace(v.camera, world_to_cam=v.camera.world_to_cam + np.eye(4, k=3) * 0.01) for v in theirs]
    assert not np.allclose(moved[0].world_to_cam, theirs[0].camera.world_to_cam)
    art.write_cameras(moved_dir, moved)
    shifted = repair_views(coarse_inputs(dirs["scene"], dirs["mask"], dirs["hull"]).views, moved_dir)
    for view, cam in zip(shifted, moved, strict=True):
        assert np.allclose(view.camera.world_to_cam, cam.world_to_cam)


@pytest.mark.parametrize("phase", ["coarse", "repair"])
def test_consensus_killed_in_a_phase_resumes_bit_identically(upstream, tmp_path, monkeypatch, phase):
    """A run killed inside the second model's coarse fit or repair resumes at that phase's checkpoint (a
    finished coarse phase is not fitted again) and writes the same bytes as an uninterrupted run."""
    from go_pipeline.steps import repair

    from go_core.repair import second_model

    _, dirs, weights = upstream
    tune_dir = _tune(tmp_path, dirs, {**weights, **LORA, "checkpoint_every": 0}).out_dir
    inputs, params = {**dirs, "tune": tune_dir}, step_params(repair.__name__, REPAIR)
    whole = FakeCtx(tmp_path / "whole", "repair")
    repair.run(whole, inputs, params)

    real = {"coarse": second_model.fit_coarse, "repair": second_model.repair_gaussians}[phase]
    kill_at = {"coarse": 12, "repair": 7}[phase]  # past a checkpoint (every 8 / every 5 steps)

    def killed(*args, **kw):
        progress = args[4] if phase == "coarse" else args[7]

        def stop(step, info):
            if step == kill_at:
                raise _Killed(phase)
            progress(step, info)

        args = (*args[:4], stop) if phase == "coarse" else (*args[:7], stop)
        return real(*args, **kw)

    name = {"coarse": "fit_coarse", "repair": "repair_gaussians"}[phase]
    monkeypatch.setattr(second_model, name, killed)
    ctx = FakeCtx(tmp_path / "killed", "repair")
    with pytest.raises(_Killed):
        repair.run(ctx, inputs, params)
    assert not (ctx.out_dir / "gaussians.npz").exists()
    monkeypatch.setattr(second_model, name, real)
    genuine_fit, resumed = second_model.fit_coarse, []

    def spy(*args, **kw):
        out = genuine_fit(*args, **kw)
        resumed.append(out[1].resumed_from)
        return out

    monkeypatch.setattr(second_model, "fit_coarse", spy)
    repair.run(ctx, inputs, params)
    assert resumed == ([8] if phase == "coarse" else [])  # a finished coarse phase is not fitted again
    assert _gaussians_bytes(ctx.out_dir) == _gaussians_bytes(whole.out_dir)
