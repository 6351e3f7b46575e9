"""The coarse-stage steps end to end on a tiny synthetic scene:
mask → hull → depth (skipped) → coarse → export → turntable."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
import torch

from go_core.camera import look_at
from go_core.gaussians import Gaussians
from go_core.ply import load_ply
from go_core.render import render_gaussians
from go_core.scene.artifact import load_scene_artifact, save_scene_artifact
from go_core.scene.types import Scene, View
from go_pipeline.pipeline import step_params

SIZE = 32


class Ctx:
    """The StepContext protocol (steps/_api.py), in memory."""

    def __init__(self, root: Path, step: str, seed: int = 0) -> None:
        self.step = step
        self.out_dir = root / step
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.checkpoint_dir = root / f"{step}_ckpt"
        self.seed = seed
        self.device = "cpu"
        self.log = logging.getLogger(step)
        self.records: dict = {}

    def progress(self, total, description="", completed=0):
        class P:
            def advance(self, n=1, **fields):
                pass

            def close(self):
                pass

        return P()

    def record(self, **values):
        self.records.update(values)


pytestmark = pytest.mark.usefixtures("single_thread")  # small tensors: one thread is faster


def _scene(root: Path) -> Path:
    g = torch.Generator().manual_seed(0)
    n = 60
    gt = Gaussians.from_points(
        torch.randn(n, 3, generator=g) * 0.3, torch.rand(n, 3, generator=g), torch.full((n,), 0.15), 0.9, 0
    )
    K = np.array([[40.0, 0, SIZE / 2], [0, 40.0, SIZE / 2], [0, 0, 1]])
    views = []
    for i in range(6):
        a = 2 * np.pi * i / 6 + (0.3 if i % 2 else 0.0)
        pos = np.array([3 * np.cos(a), 3 * np.sin(a), 1.0 if i < 4 else -0.5])
        cam = look_at(f"r_{i}", pos, np.zeros(3), np.array([0, 0, 1.0]), K, SIZE, SIZE)
        with torch.no_grad():
            out = render_gaussians(gt, cam.viewmat_tensor()[None], cam.K_tensor()[None], SIZE, SIZE)
        alpha = out.alpha[0, ..., 0].clamp(0, 1)
        rgb = (out.rgb[0] / alpha.clamp_min(1e-6)[..., None]).clamp(0, 1)
        views.append(View(cam, rgb.numpy().astype(np.float32), alpha.numpy().astype(np.float32)))
    scene = Scene(root / "raw", "nerf", views[:4], views[4:])
    out_dir = root / "scene"
    save_scene_artifact(scene, out_dir)
    return out_dir


def test_steps_end_to_end(tmp_path):
    from go_pipeline.steps import coarse, depth, export, hull, mask, turntable
    from go_pipeline.steps.registry import STEPS

    from go_pipeline.skipping import param_skip, write_skipped_outputs

    inputs = {"scene": _scene(tmp_path)}
    ctx = Ctx(tmp_path, "mask")
    mask.run(ctx, inputs, step_params(mask.__name__, {"method": "auto"}))
    assert ctx.records["method"] == "provided"
    inputs["mask"] = ctx.out_dir

    ctx = Ctx(tmp_path, "hull")
    hull.run(ctx, inputs, step_params(hull.__name__, {"num_points": 500}))
    info = json.loads((ctx.out_dir / "hull.json").read_text())
    assert info["points"] == 500 and info["volume"] > 0
    inputs["hull"] = ctx.out_dir

    ctx = Ctx(tmp_path, "depth")  # without a depth model the runner skips the step, as here
    declared = STEPS[depth.__name__]
    record = param_skip(declared.skip_if_empty, {"model_path": ""})
    assert record["status"] == "skipped"
    write_skipped_outputs(ctx.out_dir, tuple(a.file for a in declared.outputs), record, "depth")
    inputs["depth"] = ctx.out_dir

    params = {
        "iterations": 30,
        "schedule_iterations": 0,  # the schedules below as written (not scaled from the paper's 10 000)
        "densify_from": 5,
        "densify_until": 25,
        "densify_every": 5,
        "opacity_reset_every": 15,
        "floater_every": 10,
        "floater_from": 10,
        "floater_until": 20,
        "sh_increase_every": 10,
        "checkpoint_every": 10,
    }
    ctx = Ctx(tmp_path, "coarse")
    coarse.run(ctx, inputs, step_params(coarse.__name__, params))
    rec = ctx.records
    assert rec["gaussians"] > 0 and rec["depth_loss"].startswith("off")
    first = (ctx.out_dir / "gaussians.npz").read_bytes()
    report = json.loads((ctx.out_dir / "coarse.json").read_text())
    assert report["config"]["iterations"] == 30 and len(report["floater_passes"]) == 2
    curves = (ctx.out_dir / "curves.csv").read_text().splitlines()
    assert curves[0].startswith("iteration,loss,train_psnr,gaussians,") and curves[-1].startswith("30,")
    assert 5.0 < float(curves[-1].split(",")[2]) < 60.0  # a PSNR in dB, not a loss
    # a second run in a fresh out dir with the same checkpoint dir resumes from step 20: identical bytes
    ctx2 = Ctx(tmp_path, "coarse")
    ctx2.out_dir = tmp_path / "coarse_again"
    ctx2.out_dir.mkdir()
    coarse.run(ctx2, inputs, step_params(coarse.__name__, params))
    assert ctx2.records["resumed_from"] == 20
    g1 = np.load(ctx.out_dir / "gaussians.npz")
    g2 = np.load(ctx2.out_dir / "gaussians.npz")
    assert all(np.array_equal(g1[k], g2[k]) for k in g1.files) and len(first) > 0
    assert (ctx.out_dir / "coarse.json").read_bytes() == (ctx2.out_dir / "coarse.json").read_bytes()
    inputs["coarse"] = ctx.out_dir

    ctx = Ctx(tmp_path, "export")
    export.run(ctx, inputs, step_params(export.__name__, {}))
    back = load_ply(ctx.out_dir / "point_cloud.ply", sh_degree=2)
    saved = Gaussians.load(inputs["coarse"] / "gaussians.npz")
    assert torch.equal(back.means, saved.means) and torch.equal(back.sh, saved.sh)
    assert ctx.records["source"] == "coarse"

    ctx = Ctx(tmp_path, "turntable")
    turntable.run(
        ctx,
        inputs,
        step_params(
            turntable.__name__, {"frames": 6, "fps": 10, "max_size": 24, "sheet_frames": 4, "path_frames": 3}
        ),
    )
    import imageio.v3 as iio

    frames = iio.imread(ctx.out_dir / "turntable.gif", index=None)
    assert frames.shape[0] == 6 and frames.shape[1:3] == (24, 24)
    sheet = iio.imread(ctx.out_dir / "contact_sheet.png")
    assert sheet.shape[0] > 24 and sheet.shape[1] > 4 * 24
    assert frames.std() > 1.0  # the object is visible, not a blank background
    # the video along the camera path: 3 frames between consecutive training cameras, same bytes again
    import imageio_ffmpeg

    n_train = len(load_scene_artifact(inputs["scene"]).train)
    assert imageio_ffmpeg.count_frames_and_secs(str(ctx.out_dir / "camera_path.mp4"))[0] == 3 * n_train
    again = Ctx(tmp_path, "turntable2")
    turntable.run(
        again,
        inputs,
        step_params(
            turntable.__name__, {"frames": 6, "fps": 10, "max_size": 24, "sheet_frames": 4, "path_frames": 3}
        ),
    )
    assert (again.out_dir / "camera_path.mp4").read_bytes() == (ctx.out_dir / "camera_path.mp4").read_bytes()


def test_mask_step_rejects_bad_choices(tmp_path):
    from go_pipeline.steps import mask

    from go_core.config import SettingError
    from go_core.errors import PipelineError

    inputs = {"scene": _scene(tmp_path)}
    with pytest.raises(SettingError, match="method: must be one of 'auto' | 'provided'"):
        step_params(mask.__name__, {"method": "magic"})  # the runner says so at plan time
    with pytest.raises(PipelineError, match="onnx_model"):
        mask.run(
            Ctx(tmp_path, "mask"), inputs, step_params(mask.__name__, {"method": "onnx", "onnx_model": ""})
        )


def test_a_collapsed_coarse_model_is_an_error_not_a_result(tmp_path, monkeypatch):
    """When optimisation leaves almost no Gaussians (pruning never removes the last one, so the loop is
    stood in for by one that ends with 3 of 500), the step fails with CollapsedModelError and writes no
    gaussians.npz."""
    from go_pipeline.steps import coarse, hull, mask

    from go_core.coarse import fit
    from go_core.coarse.loop import TrainStats
    from go_core.errors import CollapsedModelError

    inputs = {"scene": _scene(tmp_path)}
    ctx = Ctx(tmp_path, "mask")
    mask.run(ctx, inputs, step_params(mask.__name__, {"method": "auto"}))
    inputs["mask"] = ctx.out_dir
    ctx = Ctx(tmp_path, "hull")
    hull.run(ctx, inputs, step_params(hull.__name__, {"num_points": 500}))
    inputs["hull"] = ctx.out_dir

    def collapsing(init, views, config, **kw):
        return init, TrainStats(iterations=config.iterations, initial_count=len(init), final_count=3)

    monkeypatch.setattr(fit, "optimize", collapsing)
    ctx = Ctx(tmp_path, "coarse")
    params = {"iterations": 12, "schedule_iterations": 0, "checkpoint_every": 0}
    with pytest.raises(CollapsedModelError, match=r"the model collapsed: 3 of 500 Gaussians left"):
        coarse.run(ctx, inputs, step_params(coarse.__name__, params))
    assert not (ctx.out_dir / "gaussians.npz").exists()


def test_collapse_threshold():
    from go_core.coarse.loop import TrainStats
    from go_core.errors import CollapsedModelError

    TrainStats(initial_count=20000, final_count=200).check_not_collapsed()  # 1 % left: a (small) model
    with pytest.raises(CollapsedModelError):
        TrainStats(initial_count=20000, final_count=199).check_not_collapsed()
    with pytest.raises(CollapsedModelError):
        TrainStats(initial_count=5, final_count=0).check_not_collapsed()
