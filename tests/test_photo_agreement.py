"""Poses that disagree with the photos' masks are found and left out (go_core.photos.agreement), and masks
that take in too much (a turntable disc) do not count as disagreement."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from _photo_capture import render_sphere, ring_cameras

from go_core.errors import PoseCheckError
from go_core.photos.agreement import MIN_POSE_AGREEMENT, disagreeing, pose_agreement, sfm_agreeing
from go_core.photos.sfm import SfmOutcome, SfmPhoto


def _yawed(cam, degrees: float):
    """``cam`` turned about its own vertical axis: the object lands ``f tan(degrees)`` px aside."""
    a = np.radians(degrees)
    turn = np.eye(4)
    turn[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    return replace(cam, world_to_cam=turn @ cam.world_to_cam)


@pytest.fixture(scope="module")
def ring():
    cams = ring_cameras(16, 96)
    masks = [render_sphere(c, 0)[1] for c in cams]
    for k in (1, 2, 3):  # a disc under the object that these photos' masks take in (right poses)
        masks[k] = masks[k].copy()
        masks[k][60:, :] = 1.0
    return cams, masks


def test_a_wrong_pose_disagrees_and_an_over_inclusive_mask_does_not(ring):
    cams, masks = ring
    names = [c.name for c in cams]
    right = np.asarray(pose_agreement(masks, cams))
    assert right.min() > MIN_POSE_AGREEMENT * np.median(right), right
    assert disagreeing([c.name for c in cams], masks, cams) == {}
    posed = list(cams)
    posed[8] = _yawed(cams[8], 12.0)  # 1.4 * 96 * tan(12 deg) = 29 px off a sphere of radius ~42 px
    found = disagreeing(names, masks, posed)
    assert list(found) == ["v08"] and found["v08"] < MIN_POSE_AGREEMENT


def _photos(cams, masks) -> list[SfmPhoto]:
    return [SfmPhoto(c.name, np.zeros((96, 96, 3), np.float32), m) for c, m in zip(cams, masks, strict=True)]


def _outcome(cams: dict) -> SfmOutcome:
    return SfmOutcome(cams, {n: 0.0 for n in cams}, [], 0.4, {}, {}, 100, 10, 10, True)


def test_sfm_runs_again_without_the_disagreeing_photo(ring):
    cams, masks = ring
    photos = [
        SfmPhoto(c.name, np.zeros((96, 96, 3), np.float32), m) for c, m in zip(cams, masks, strict=True)
    ]
    calls = []

    def run(some):
        calls.append([p.name for p in some])
        posed = {c.name: c for c in cams if c.name in calls[-1]}
        if len(calls) == 1:
            posed["v08"] = _yawed(cams[8], 12.0)
        return _outcome(posed)

    out, left_out = sfm_agreeing(photos, run)
    assert len(calls) == 2 and "v08" not in calls[1] and len(calls[1]) == 15
    assert list(left_out) == ["v08"] and out.missing == ["v08"] and "v08" not in out.cameras


def test_poses_that_keep_disagreeing_are_an_error(ring):
    cams, masks = ring
    photos = [
        SfmPhoto(c.name, np.zeros((96, 96, 3), np.float32), m) for c, m in zip(cams, masks, strict=True)
    ]

    def run(some):  # every run poses the first photo it is given wrong
        posed = {p.name: cams[int(p.name[1:])] for p in some}
        first = some[0].name
        posed[first] = _yawed(posed[first], 12.0)
        return _outcome(posed)

    with pytest.raises(PoseCheckError, match="disagree with their masks after 3 reruns"):
        sfm_agreeing(photos, run)
