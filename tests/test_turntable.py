"""Turntable path: on the ellipse fitted to the TRAINING cameras, looking at their look-at point."""

from __future__ import annotations

import numpy as np
import pytest

from go_core.camera import fit_ellipse, look_at, look_at_point
from go_core.render.trajectory import contact_sheet, turntable_cameras

pytestmark = pytest.mark.usefixtures("single_thread")  # small tensors: one thread is faster


def _ring(n, radius, height, size=64, phase=0.0):
    K = np.array([[50.0, 0, size / 2], [0, 50.0, size / 2], [0, 0, 1]])
    out = []
    for i in range(n):
        a = phase + 2 * np.pi * i / n
        pos = np.array([radius * np.cos(a), radius * np.sin(a), height])
        out.append(look_at(f"c{i}", pos, np.zeros(3), np.array([0, 0, 1.0]), K, size, size))
    return out


def test_turntable_lies_on_the_training_ellipse_and_looks_at_the_centre():
    train = _ring(4, 3.0, 1.0)
    cams = turntable_cameras(train, 12)
    assert len(cams) == 12
    centers = np.stack([c.center for c in cams])
    assert np.allclose(centers[:, 2], 1.0, atol=1e-6)
    assert np.allclose(np.linalg.norm(centers[:, :2], axis=1), 3.0, atol=1e-6)
    assert np.allclose(centers[0], train[0].center, atol=1e-6)  # starts at the first training view
    target = look_at_point(cams)
    assert np.allclose(target, 0.0, atol=1e-6)
    for c in cams:  # image 'up' points to +z
        assert c.up[2] > 0.5


def test_test_cameras_never_shape_the_path():
    train = _ring(4, 3.0, 1.0)
    test = _ring(6, 5.0, 3.0, phase=0.4)
    path = turntable_cameras(train, 8)
    leaky = fit_ellipse(train + test)  # what fitting to all cameras would give
    assert not np.isclose(leaky.a, 3.0, atol=0.1)
    assert all(np.isclose(np.linalg.norm(c.center[:2]), 3.0, atol=1e-6) for c in path)


def test_max_size_and_contact_sheet():
    cams = turntable_cameras(_ring(4, 3.0, 1.0, size=200), 5, max_size=100)
    assert (cams[0].width, cams[0].height) == (100, 100)
    frames = [np.full((10, 12, 3), i * 40, np.uint8) for i in range(6)]
    sheet = contact_sheet(frames, 4, columns=2, pad=2)
    assert sheet.shape == (2 * 12 + 2, 2 * 14 + 2, 3)
    assert sheet[2, 2, 0] == 0 and sheet[2 + 12, 2 + 14, 0] == 200  # first and last of the picks (0, 5)
