"""The camera path of camera_path.mp4: through every training camera, smooth, closed."""

from __future__ import annotations

import numpy as np

from go_core.camera import look_at
from go_core.render.trajectory import camera_path_cameras


def _ring(n: int, radius: float = 3.0):
    K = np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])
    cams = []
    for i, theta in enumerate(np.linspace(0, 2 * np.pi, n, endpoint=False)[[2, 0, 3, 1]]):  # shuffled
        pos = np.array([radius * np.cos(theta), radius * np.sin(theta), 0.5 + 0.1 * i])
        cams.append(look_at(f"c{i}", pos, np.zeros(3), np.array([0, 0, 1.0]), K, 100, 100))
    return cams


def test_path_passes_through_each_training_camera_in_angle_order():
    cams = _ring(4)
    path = camera_path_cameras(cams, 5)
    assert len(path) == 20
    # every 5th frame is a training camera (pose equal to float precision), in order around the ring
    hits = [path[5 * k] for k in range(4)]
    for cam in hits:
        match = [np.abs(cam.world_to_cam - c.world_to_cam).max() < 1e-9 for c in cams]
        assert sum(match) == 1
    order = [
        next(i for i, c in enumerate(cams) if np.abs(h.world_to_cam - c.world_to_cam).max() < 1e-9)
        for h in hits
    ]
    # around the ring (either way): c0 (theta pi), then c3 (3pi/2) or c2 (pi/2), ...
    assert order in ([0, 3, 1, 2], [0, 2, 1, 3])


def test_path_is_smooth_and_keeps_its_distance_to_the_object():
    cams = _ring(4)
    path = camera_path_cameras(cams, 12)
    centres = np.stack([c.center for c in path])
    steps = np.linalg.norm(np.diff(np.vstack([centres, centres[:1]]), axis=0), axis=1)
    assert steps.max() < 1.5 * steps.min()  # no jumps, closed loop
    radii = np.linalg.norm(centres[:, :2], axis=1)
    assert np.allclose(radii, 3.0, atol=0.1)  # an arc around the object (a chord would come to 2.12)
    for c in path:  # every frame still looks at the object
        to_obj = -c.center / np.linalg.norm(c.center)
        assert c.forward @ to_obj > 0.99
