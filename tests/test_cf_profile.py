"""The COLMAP-free profile: training poses estimated in the scene step (verified, else one error naming the
views), refined in coarse, and the test poses aligned in eval (metrics marked as CF)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from go_core.camera import Camera, look_at_point
from go_core.poses.similarity import Similarity

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
    import go_core.poses.sfm as sfm
    from go_pipeline.runner import run_pipeline

    def fake_sfm(views, **kw):
        cams = {v.name: PLANTED.camera(v.camera) for v in views}
        return sfm.SfmResult(cams, 0.4, {v.name: 500 for v in views}, 800, 6)

    monkeypatch.setattr(sfm, "reconstruct", fake_sfm)
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


def _copy_with_initial_poses(tmp_path: Path, frames: list[dict] | None) -> Path:
    """The example scene with ``initial_poses.json`` holding ``frames`` (None: the planted SfM frame)."""
    import shutil

    from go_core.scene.loader import load_scene

    scene_dir = tmp_path / "scene"
    shutil.copytree(EXAMPLE, scene_dir)
    if frames is None:
        frames = [
            {
                "file_path": "./train/" + v.name.removeprefix("train_"),
                "transform_matrix": c.opengl_c2w.tolist(),
            }
            for v in load_scene(EXAMPLE).train
            for c in [PLANTED.camera(v.camera)]
        ]
    (scene_dir / "initial_poses.json").write_text(json.dumps({"frames": frames}))
    return scene_dir


def test_initial_poses_replace_the_training_poses_and_keep_the_given_ones(tmp_path):
    """scene.poses=initial: the training cameras are those of initial_poses.json, the folder's own poses
    are kept as the reference, and eval treats the model as living in the initial cameras' frame."""
    from go_pipeline.runner import run_pipeline

    scene_dir = _copy_with_initial_poses(tmp_path, None)
    overrides = {"scene.poses": "initial", "weights.repair_model": "sd15", "eval.test_pose_iterations": 2}
    summary = run_pipeline(
        scene_dir, workdir=tmp_path / "w", profile="test", overrides=overrides, quiet=True, in_process=True
    )
    steps = {s.name: s for s in summary.steps}
    scene = json.loads((steps["scene"].artifact_dir / "scene.json").read_text())
    assert scene["poses"] == "initial (initial_poses.json)"
    for c in scene["train"]:
        given = Camera(
            c["name"], c["width"], c["height"], np.asarray(c["K"]), np.asarray(c["given_world_to_cam"])
        )
        np.testing.assert_allclose(c["world_to_cam"], PLANTED.camera(given).world_to_cam, atol=1e-9)
    metrics = json.loads((steps["eval"].artifact_dir / "metrics.json").read_text())
    assert metrics["poses"]["cf"] is True
    assert metrics["poses"]["similarity_scale"] == pytest.approx(PLANTED.scale, rel=1e-6)  # not refined


def _scene_step_with_initial_poses(scene_dir: Path, workdir: Path, capsys) -> tuple[int, str]:
    """``go-pipeline run SCENE --set scene.poses=initial --until scene``: exit code and stderr."""
    from go_pipeline.cli import main

    argv = ["run", str(scene_dir), "--workdir", str(workdir), "--set", "scene.poses=initial"]
    rc = main([*argv, "--until", "scene"])
    return rc, capsys.readouterr().err


@pytest.mark.parametrize(
    ("frames", "message"),
    [
        ([], "no initial pose for the training view 'train_r_0'"),
        (
            [{"file_path": "./train/r_0", "transform_matrix": np.diag([2.0, 1, 1, 1]).tolist()}],
            "not a rotation",
        ),
        ([{"file_path": "./train/r_0", "transform_matrix": [[1, 0], [0, 1]]}], "not a finite 4x4 matrix"),
        ([{"file_path": "./train/r_0"}], "not a transforms file"),
    ],
)
def test_bad_initial_poses_are_one_error_naming_the_file(tmp_path, capsys, frames, message):
    scene_dir = _copy_with_initial_poses(tmp_path, frames)
    rc, err = _scene_step_with_initial_poses(scene_dir, tmp_path / "w", capsys)
    assert rc != 0
    assert "initial_poses.json" in err and message in err
    assert "Traceback" not in err


def test_missing_initial_poses_file_is_an_error(tmp_path, capsys):
    rc, err = _scene_step_with_initial_poses(EXAMPLE, tmp_path / "w", capsys)
    assert rc != 0 and "scene.poses=initial needs initial_poses.json" in err


def test_hull_alignment_turns_perturbed_cameras_back_and_coarse_starts_from_them(tmp_path):
    """hull.align_poses on the example with every training camera turned by 4°: the hull's cameras.json
    moves them back towards the truth (object points reproject closer), coarse fits with those cameras
    (its cameras.json says aligned), and eval uses the CF protocol."""
    from go_core import artifacts as art
    from go_core.poses.similarity import similarity_from_cameras
    from go_core.scene.loader import load_scene
    from go_pipeline.runner import run_pipeline

    truth = load_scene(EXAMPLE, max_size=64).train_cameras  # the test profile's scene.max_size
    rng = np.random.default_rng(3)
    frames = []
    for cam in truth:
        c2w = cam.opengl_c2w.copy()
        axis = rng.normal(size=3)
        c2w[:3, :3] = (
            c2w[:3, :3] @ Rotation.from_rotvec(np.radians(4.0) * axis / np.linalg.norm(axis)).as_matrix()
        )
        frames.append(
            {"file_path": "./train/" + cam.name.removeprefix("train_"), "transform_matrix": c2w.tolist()}
        )
    scene_dir = _copy_with_initial_poses(tmp_path, frames)
    overrides = {
        "scene.poses": "initial",
        "hull.align_poses": True,
        "hull.align_iterations": 40,
        "weights.repair_model": "sd15",
        "eval.test_pose_iterations": 2,
    }
    summary = run_pipeline(
        scene_dir,
        workdir=tmp_path / "w",
        profile="test",
        overrides=overrides,
        until="eval",
        quiet=True,
        in_process=True,
    )
    steps = {s.name: s for s in summary.steps}
    start = art.read_scene(steps["scene"].artifact_dir).train_cameras
    aligned = art.read_cameras(steps["hull"].artifact_dir)
    points = np.random.default_rng(0).normal(size=(400, 3)) * 0.2 + look_at_point(truth)

    def error_px(cams):
        sim = similarity_from_cameras(truth, cams)
        mapped = sim.points(points)
        return np.mean(
            [
                np.linalg.norm(c.project(mapped)[0] - sim.camera(t).project(mapped)[0], axis=1).mean()
                for c, t in zip(cams, truth, strict=True)
            ]
        )

    print("reprojection px before/after the hull alignment:", error_px(start), error_px(aligned))
    assert error_px(aligned) < 0.5 * error_px(start)
    coarse = art.read_json(steps["coarse"].artifact_dir, art.CAMERAS)
    assert coarse["aligned"] is True and coarse["refined"] is True
    np.testing.assert_allclose(coarse["cameras"][1]["world_to_cam"], aligned[1].world_to_cam, atol=1e-12)
    metrics = json.loads((steps["eval"].artifact_dir / "metrics.json").read_text())
    assert metrics["poses"]["cf"] is True
