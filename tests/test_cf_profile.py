"""The COLMAP-free profile: training poses estimated in the scene step (verified, else one error naming the
views), refined in coarse, and the test poses aligned in eval (metrics marked as CF)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from go_core.alignment import Similarity
from go_core.camera import Camera

EXAMPLE = Path(__file__).resolve().parents[1] / "go_pipeline" / "examples" / "basket"
TURN = Rotation.from_euler("xyz", [20, -35, 50], degrees=True).as_matrix()
PLANTED = Similarity(0.5, TURN, np.array([1.0, -2.0, 0.5]))  # an arbitrary SfM frame


def test_estimation_that_registers_nothing_is_one_error_naming_the_views(tmp_path, capsys):
    from go_pipeline.cli import main

    rc = main(["run", str(EXAMPLE), "--workdir", str(tmp_path / "w"), "--profile", "cf", "--until", "scene"])
    err = capsys.readouterr().err
    assert rc != 0
    views = "train_r_0, train_r_1, train_r_2, train_r_3"
    assert f"scene.poses=estimate: no poses for the training views ({views})" in err
    assert "Traceback" not in err


def test_estimated_poses_flow_to_a_cf_evaluation(tmp_path, monkeypatch):
    """SfM is replaced by the scene's own training cameras moved by a planted similarity (an SfM frame):
    the scene step takes them (keeping the given poses), coarse refines in that frame, and eval recovers
    the planted similarity to align the test cameras."""
    import go_core.posecheck as posecheck
    from go_pipeline.runner import run_pipeline

    def fake_sfm(views, **kw):
        cams = {v.name: PLANTED.camera(v.camera) for v in views}
        return posecheck.SfmResult(cams, 0.4, {v.name: 500 for v in views}, 800, 6)

    monkeypatch.setattr(posecheck, "reconstruct", fake_sfm)
    overrides = {
        "scene.poses": "estimate",
        "coarse.refine_poses": True,
        "coarse.pose_refine_from": 0,
        "weights.repair_model": "sd15",  # no SD weights: the repair chain skips, eval scores coarse
        "eval.test_pose_iterations": 3,
    }
    work = tmp_path / "w"
    summary = run_pipeline(
        EXAMPLE, workdir=work, profile="test", overrides=overrides, quiet=True, in_process=True
    )
    steps = {s.name: s for s in summary.steps}
    scene = json.loads((steps["scene"].artifact_dir / "scene.json").read_text())
    assert scene["poses"] == "estimated (sift, verified)"
    for c in scene["train"]:  # the estimated cameras are in scene.json, the folder's own poses beside them
        w2c = np.asarray(c["given_world_to_cam"])
        given = Camera(c["name"], c["width"], c["height"], np.asarray(c["K"]), w2c)
        np.testing.assert_allclose(c["world_to_cam"], PLANTED.camera(given).world_to_cam, atol=1e-9)
    metrics = json.loads((steps["eval"].artifact_dir / "metrics.json").read_text())
    assert metrics["poses"]["cf"] is True
    assert metrics["poses"]["similarity_scale"] == pytest.approx(PLANTED.scale, rel=0.02)
    assert metrics["mean"]["psnr"] > 10.0
