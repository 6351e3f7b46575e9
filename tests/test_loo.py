"""The loo step: leave-one-out runs, pairs and statistics; a killed step resumes without redoing runs."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from go_core.gaussians import Gaussians
from go_core.repair.noise import difference_stats
from go_pipeline.pipeline import step_params
from tests._tiny_repair import FakeCtx, one_thread, synthetic_inputs

PARAMS = {"phase1_iterations": 20, "phase2_iterations": 10, "renders": 3, "checkpoint_every": 10}


@pytest.fixture(autouse=True)
def _threads():
    with one_thread():
        yield


@pytest.fixture(scope="module")
def done(tmp_path_factory):
    """Inputs and one uninterrupted loo run."""
    from go_pipeline.steps import loo

    root = tmp_path_factory.mktemp("loo")
    with one_thread():
        dirs = synthetic_inputs(root)
        ctx = FakeCtx(root, "loo")
        loo.run(ctx, dirs, step_params(loo.__name__, PARAMS))
    return root, dirs, ctx


def test_loo_pairs_and_statistics(done):
    root, dirs, ctx = done
    info = json.loads((ctx.out_dir / "loo.json").read_text())
    assert len(info["runs"]) == 4 and len(info["pairs"]) == 4 * 3
    assert ctx.records["runs"] == 4 and ctx.records["pairs"] == 12
    # progress: one bar per run over both phases (with loss and Gaussian count), and one over the runs
    inner = [b for b in ctx.bars if b.description.startswith("run ")]
    assert [(b.n, b.total) for b in inner] == [(30, 30)] * 4
    assert inner[0].description.startswith("run 1/4 (without ") and inner[0].fields["gaussians"] > 0
    assert [(b.n, b.total) for b in ctx.bars if b not in inner] == [(4, 4)]
    with np.load(ctx.out_dir / "loo_pairs.npz") as data:
        for p in info["pairs"]:
            deg, clean = data[p["degraded"]], data[p["clean"]]
            assert deg.shape == (64, 64, 4) and clean.shape == (64, 64, 3) and deg.dtype == np.uint8
            # RGBA: the render on white and its alpha; where the render is empty it is white
            empty = deg[..., 3] == 0
            assert empty.any() and (deg[..., :3][empty] >= 254).all()
        # the degraded renders of one view change over phase 2 (they are taken at different iterations)
        assert not np.array_equal(data["degraded_0_0"], data["degraded_0_2"])
    steps = [p["phase2_step"] for p in info["pairs"] if p["view"] == 0]
    assert steps == [1, 10, 11]  # first and last phase-2 iteration, plus the final state
    # the statistics are those of (phase 2 - phase 1) over the same Gaussians of every run
    pairs = []
    for k in range(4):
        run = ctx.checkpoint_dir / f"run_{k:02d}"
        before, after = Gaussians.load(run / "before.npz"), Gaussians.load(run / "after.npz")
        assert len(before) == len(after)
        assert not torch.equal(before.means, after.means)
        pairs.append((before, after))
    stats = difference_stats(pairs)
    assert info["stats"] == json.loads(json.dumps(stats.to_json()))
    assert all(s > 0 for s in stats.std["means"])


def test_killed_loo_resumes_without_redoing_finished_runs(done, tmp_path, monkeypatch):
    from go_pipeline.steps import loo

    from go_core.repair import loo as core

    _, dirs, first = done
    calls: list[int] = []
    original = core.run_one

    def flaky(index, *a, **k):
        calls.append(index)
        if index == 2 and calls.count(2) == 1:
            raise KeyboardInterrupt("simulated kill")
        return original(index, *a, **k)

    monkeypatch.setattr(loo, "run_one", flaky)
    ctx = FakeCtx(tmp_path, "loo")
    with pytest.raises(KeyboardInterrupt):
        loo.run(ctx, dirs, step_params(loo.__name__, PARAMS))
    assert calls == [0, 1, 2]
    ctx2 = FakeCtx(tmp_path, "loo")  # same checkpoint folder, fresh output folder
    loo.run(ctx2, dirs, step_params(loo.__name__, PARAMS))
    assert calls == [0, 1, 2, 2, 3]  # finished runs 0 and 1 are not run again
    for name in ("loo.json", "loo_pairs.npz"):
        assert (ctx2.out_dir / name).read_bytes() == (first.out_dir / name).read_bytes()


@pytest.mark.slow
def test_parallel_workers_give_the_same_artifacts(done, tmp_path):
    from go_pipeline.steps import loo

    _, dirs, first = done
    ctx = FakeCtx(tmp_path, "loo")
    loo.run(ctx, dirs, step_params(loo.__name__, {**PARAMS, "workers": 2}))
    assert ctx.records["workers"] == 2
    for name in ("loo.json", "loo_pairs.npz"):
        assert (ctx.out_dir / name).read_bytes() == (first.out_dir / name).read_bytes()


def test_compressed_schedule_scales_every_step_schedule_to_phase_one():
    from go_core.coarse.loop import CoarseConfig

    # 10 000 its: densify 500..6000 every 100, reset 1000, floaters 500..6000 every 500
    base = CoarseConfig(iterations=10_000)
    c = base.compressed(1000)
    assert c.iterations == 1000 and c.sh_increase_every == 100 and c.position_lr_max_steps == 3000
    assert (c.densify_from, c.densify_until, c.densify_every, c.opacity_reset_every) == (50, 600, 10, 100)
    assert (c.floater_from, c.floater_until, c.floater_every) == (50, 600, 50)
    assert c.densify_grad_threshold == base.densify_grad_threshold and c.feature_lr == base.feature_lr
    assert base.compressed(20_000) == replace(base, iterations=20_000)  # never stretched


def test_runs_on_downscaled_views_keep_their_renders_and_photos_at_full_size(done, tmp_path):
    """loo.train_size: the runs train on views at half size; the left-out view is rendered, and its photo
    kept, at full size, so the pairs look as without it (and the same photos are the clean images)."""
    from go_pipeline.steps import loo

    from go_core.repair.data import training_views
    from go_core.repair.loo import downscaled

    root, dirs, full_ctx = done
    _, views = training_views(dirs["scene"], dirs.get("mask"), dirs["coarse"])
    small = downscaled(views, 32)
    assert [(v.camera.width, v.camera.height) for v in small] == [(32, 32)] * len(views)
    assert np.allclose(small[0].camera.K[:2], views[0].camera.K[:2] * 0.5)
    assert torch.allclose(small[0].image, views[0].image.reshape(32, 2, 32, 2, 3).mean((1, 3)), atol=1e-6)
    assert downscaled(views, 64)[0] is views[0] and downscaled(views, 0)[0] is views[0]

    ctx = FakeCtx(tmp_path, "loo")
    loo.run(ctx, dirs, step_params(loo.__name__, {**PARAMS, "train_size": 32}))
    with np.load(ctx.out_dir / "loo_pairs.npz") as data, np.load(full_ctx.out_dir / "loo_pairs.npz") as full:
        assert data["degraded_0_2"].shape == (64, 64, 4)  # RGB on white + the render's alpha
        assert np.array_equal(data["clean_0"], full["clean_0"]) and np.array_equal(
            data["mask_0"], full["mask_0"]
        )
        assert not np.array_equal(data["degraded_0_2"], full["degraded_0_2"])  # trained on other pixels


def test_loo_workers_auto_is_one_process_per_thread_on_a_cpu_and_one_on_cuda():
    from go_pipeline.steps.loo import loo_workers

    assert loo_workers(0, 4, "cpu", 2) == (2, 1)  # the 2-core case: two runs at a time, one thread each
    assert loo_workers(0, 4, "cpu", 16) == (4, 4)  # never more processes than runs; threads shared out
    assert loo_workers(0, 4, "cpu", 1) == (1, 1)
    assert loo_workers(0, 4, "cuda:0", 16) == (1, 16)
    assert loo_workers(3, 4, "cpu", 2) == (3, 1)  # asked for: as asked
