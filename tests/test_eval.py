"""The eval step end to end through the runner (toy scene rendered from known Gaussians)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from _eval_toy import make_eval_toy
from PIL import Image

from go_core.metrics.lpips_weights import weights_path
from go_core.metrics.psnr import psnr
from go_core.scene.artifact import load_scene_artifact
from go_pipeline.runner import run_pipeline

HAVE_WEIGHTS = all(weights_path(n).exists() for n in ("alex", "vgg"))


@pytest.fixture()
def toy(tmp_path):
    return make_eval_toy(tmp_path)


def _run(toy, scene, tmp_path, **overrides):
    return run_pipeline(
        scene,
        workdir=tmp_path / "wd",
        pipeline_path=toy.pipeline,
        overrides=overrides,
        in_process=True,
        quiet=True,
    )


def test_eval_exact_model_scores_perfectly(toy, tmp_path):
    scene = toy.scene(tmp_path, "s1")
    summary = _run(toy, scene, tmp_path)
    out = summary.step("eval").artifact_dir
    m = json.loads((out / "metrics.json").read_text())
    assert m["model"] == "coarse" and m["model_reason"] == "no repair step in this pipeline"
    assert m["num_gaussians"] == 300 and len(m["views"]) == 3
    # GT = straight colour composited on white with its alpha == the render on white (float16 storage)
    assert m["mean"]["psnr"] > 45 and m["mean"]["ssim"] > 0.999
    if HAVE_WEIGHTS:
        assert m["lpips_status"] == {"vgg": "ok", "alex": "ok"}
        assert m["mean"]["lpips_vgg"] < 0.01 and m["mean"]["lpips_star"] == pytest.approx(
            100 * m["mean"]["lpips_vgg"]
        )
    grid = np.asarray(Image.open(out / "test_grid.png"))
    assert grid.shape[0] == 3 * 40 and grid.shape[1] == 3 * (40 + 2)  # rows GT/render/error, 3 columns
    assert (out / "metrics.json").stat().st_size < 20_000


def test_eval_metrics_match_direct_computation(toy, tmp_path):
    scene = toy.scene(tmp_path, "s2", seed="2")
    summary = _run(toy, scene, tmp_path, **{"coarse.color_noise": 0.3})
    m = json.loads((summary.step("eval").artifact_dir / "metrics.json").read_text())
    assert 10 < m["mean"]["psnr"] < 40
    # recompute view 0 independently: render the perturbed model on white vs GT composited on white
    from go_core.gaussians import Gaussians
    from go_core.render import render_gaussians

    sc = load_scene_artifact(summary.step("scene").artifact_dir)
    g = Gaussians.load(summary.step("coarse").artifact_dir / "gaussians.npz")
    v = sc.test[0]
    with torch.no_grad():
        r = (
            render_gaussians(
                g,
                v.camera.viewmat_tensor()[None],
                v.camera.K_tensor()[None],
                40,
                40,
                background=torch.ones(3),
            )
            .rgb[0]
            .clamp(0, 1)
        )
    gt = torch.from_numpy(v.image * v.mask[..., None] + (1 - v.mask[..., None]))
    assert m["views"][0]["psnr"] == pytest.approx(psnr(r, gt), abs=1e-4)
    assert m["mean"]["psnr"] == pytest.approx(np.mean([x["psnr"] for x in m["views"]]))


def test_eval_without_weights_records_lpips_unavailable(toy, tmp_path, monkeypatch):
    monkeypatch.setenv("GO_PIPELINE_CACHE", str(tmp_path / "empty-cache"))
    scene = toy.scene(tmp_path, "s3")
    summary = _run(toy, scene, tmp_path, **{"eval.masked": True})
    m = json.loads((summary.step("eval").artifact_dir / "metrics.json").read_text())
    assert (
        m["mean"]["lpips_vgg"] is None and m["mean"]["lpips_alex"] is None and m["mean"]["lpips_star"] is None
    )
    assert "go-pipeline weights fetch" in m["lpips_status"]["vgg"]
    assert m["views"][0]["masked"]["psnr"] is None or m["views"][0]["masked"]["psnr"] > 40
    assert m["mean"]["masked"]["ssim"] > 0.99
    assert summary.step("eval").record["lpips_vgg"] is None
