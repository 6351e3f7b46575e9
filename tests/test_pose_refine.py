"""Pose corrections through the rasterizer's viewmat gradients: a planted 3° rotation (plus a 2%-of-distance
shift) of a camera is recovered against a frozen synthetic scene to under 0.5°."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from go_core.camera import Camera, look_at
from go_core.gaussians import Gaussians
from go_core.poses.refine import PoseCorrection, refine_pose, rotation_angle_deg, so3_exp
from go_core.render import render_camera
from go_core.render.synthetic import random_scene


def test_so3_exp_matches_scipy_and_is_smooth_at_zero():
    w = torch.tensor([[0.1, -0.2, 0.3], [1e-9, 0.0, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
    R = so3_exp(w).numpy()
    np.testing.assert_allclose(R, Rotation.from_rotvec(w.numpy()).as_matrix(), atol=1e-12)
    z = torch.zeros(1, 3, dtype=torch.float64, requires_grad=True)
    so3_exp(z)[0, 0, 1].backward()  # d R[0,1] / d ω_z = -1 at 0
    np.testing.assert_allclose(z.grad.numpy(), [[0.0, 0.0, -1.0]], atol=1e-12)


def test_fixed_views_keep_their_pose():
    corr = PoseCorrection(3, fixed=(0,))
    with torch.no_grad():
        corr.rotation.fill_(0.1)
        corr.translation.fill_(0.2)
    D = corr.matrices()
    assert torch.equal(D[0], torch.eye(4)) and not torch.equal(D[1], torch.eye(4))


def test_camera_turned_is_a_rotation_only_pose_correction():
    """``Camera.turned`` (numpy, the pose check's turns) equals ``PoseCorrection`` with no translation
    (torch, the refinement's): same centre, turned by |rotvec|."""
    K = np.array([[50.0, 0, 32], [0, 50.0, 32], [0, 0, 1]])
    cam = look_at("c", np.array([0.3, -1.2, 2.5]), np.zeros(3), np.array([0, 0, 1.0]), K, 64, 64)
    rotvec = np.array([0.05, -0.02, 0.03])
    corr = PoseCorrection(1)
    with torch.no_grad():
        corr.rotation.copy_(torch.as_tensor(rotvec[None]))
    np.testing.assert_allclose(
        cam.turned(rotvec).world_to_cam, corr.apply_to([cam])[0].world_to_cam, atol=1e-7
    )
    np.testing.assert_allclose(cam.turned(rotvec).center, cam.center, atol=1e-12)
    angle = rotation_angle_deg(cam.turned(rotvec).world_to_cam, cam.world_to_cam)
    assert angle == pytest.approx(np.degrees(np.linalg.norm(rotvec)), abs=1e-9)


@pytest.fixture(scope="module")
def scene():
    means, quats, scales, opac, sh, vms, Ks = random_scene(600, 64, 64, cams=1, sh_degree=0, seed=3)
    g = Gaussians(means.float(), quats.float(), scales.log().float(), torch.logit(opac).float(), sh.float())
    cam = Camera("c", 64, 64, Ks[0].double().numpy(), vms[0].double().numpy())
    return g, cam


def _perturbed(cam: Camera, degrees: float, shift: float, seed: int = 0) -> Camera:
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    R = Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix()
    w2c = np.eye(4)
    w2c[:3, :3] = R @ cam.world_to_cam[:3, :3]
    center = cam.center + shift * np.linalg.norm(cam.center) * rng.normal(size=3) / np.sqrt(3)
    w2c[:3, 3] = -w2c[:3, :3] @ center
    return Camera(cam.name, cam.width, cam.height, cam.K, w2c)


def test_refine_pose_recovers_a_planted_3_degree_error(scene):
    g, cam = scene
    with torch.no_grad():
        target = render_camera(g, cam, background=torch.ones(3)).rgb[0]
    start = _perturbed(cam, 3.0, 0.02)
    assert rotation_angle_deg(start.world_to_cam, cam.world_to_cam) == pytest.approx(3.0, abs=1e-6)
    refined, losses = refine_pose(g, start, target, iterations=150, lr_rotation=3e-3, lr_translation=3e-3)
    err = rotation_angle_deg(refined.world_to_cam, cam.world_to_cam)
    assert err < 0.5, (err, losses[0], losses[-1])
    assert losses[-1] < 0.3 * losses[0]


# Joint refinement inside the coarse loop ------------------------------------------------------------------
NOISE = 0.01  # the start: the true Gaussians with their centres moved by this (world units)
SPREAD = 1.5  # the object fills the view: rotation and translation are told apart by parallax


def _joint_scene():
    from go_core.coarse.loop import TrainView

    scene = random_scene(800, 64, 64, cams=6, sh_degree=0, seed=5, spread=SPREAD, scale=0.08)
    means, quats, scales, opac, sh, vms, Ks = scene
    logits = torch.logit(opac).float()
    truth = Gaussians(means.float(), quats.float(), scales.log().float(), logits, sh.float())
    cams = [Camera(f"v{i}", 64, 64, Ks[i].double().numpy(), vms[i].double().numpy()) for i in range(6)]
    with torch.no_grad():
        images = [render_camera(truth, c, background=torch.ones(3)).rgb[0] for c in cams]
    noisy = [_perturbed(c, 3.0, 0.02, seed=i) if i == 3 else c for i, c in enumerate(cams)]
    views = [TrainView(c, img) for c, img in zip(noisy, images, strict=True)]
    g = torch.Generator().manual_seed(0)
    init = Gaussians(
        truth.means + NOISE * torch.randn(truth.means.shape, generator=g),
        truth.quats,
        truth.log_scales,
        truth.opacity_logits,
        truth.sh,
    )
    return cams, views, init


def _joint_config(refine: bool, iterations: int = 800):
    from go_core.coarse.settings import CoarseConfig

    return CoarseConfig(
        iterations=iterations,
        schedule_iterations=0,
        sh_degree=0,
        random_background=False,
        lambda_mask=0.0,
        densify_from=10_000,
        floaters=False,
        drop_gamma=0.0,
        lambda_opacity=0.0,
        lambda_anisotropy=0.0,
        refine_poses=refine,
        pose_refine_from=0,
        pose_lr_rotation=5e-3,
        pose_lr_translation=5e-3,
    )


def test_joint_refinement_recovers_a_planted_3_degree_error():
    from go_core.coarse.loop import optimize
    from go_core.poses.refine import apply_corrections
    from go_core.seeding import torch_generator

    cams, views, init = _joint_scene()
    before = rotation_angle_deg(views[3].camera.world_to_cam, cams[3].world_to_cam)
    assert before == pytest.approx(3.0, abs=1e-6)
    _, stats = optimize(init, views, _joint_config(True), generator=torch_generator(0, "joint"))
    refined = apply_corrections([v.camera for v in views], stats.pose_corrections)
    errors = [rotation_angle_deg(r.world_to_cam, c.world_to_cam) for r, c in zip(refined, cams, strict=True)]
    assert errors[0] == 0.0  # the gauge view keeps its pose
    assert errors[3] < 0.5, errors
    assert max(errors) < 0.5, errors  # the correct views stay correct
    _, plain = optimize(init, views, _joint_config(False), generator=torch_generator(0, "joint"))
    assert plain.pose_corrections is None


def test_joint_refinement_resumes_bit_identical(tmp_path):
    from go_core.coarse.loop import optimize
    from go_core.io.checkpoint import CheckpointSpec
    from go_core.seeding import torch_generator

    _, views, init = _joint_scene()
    config = _joint_config(True, iterations=120)
    ref_g, ref = optimize(init, views, config, generator=torch_generator(0, "joint"))

    class Kill(Exception):
        pass

    def die(step, info):
        if step == 70:
            raise Kill

    spec = CheckpointSpec(tmp_path, every=50)
    with pytest.raises(Kill):
        optimize(init, views, config, generator=torch_generator(0, "joint"), checkpoint=spec, on_progress=die)
    got_g, got = optimize(init, views, config, generator=torch_generator(0, "joint"), checkpoint=spec)
    assert got.resumed_from == 50
    assert got.pose_corrections == ref.pose_corrections
    assert torch.equal(got_g.means, ref_g.means)
