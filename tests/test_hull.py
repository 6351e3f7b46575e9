"""Visual hull: analytic volume (Steinmetz tricylinder), scale invariance, empty-hull error, colours."""

from __future__ import annotations

import numpy as np
import pytest

from go_core.camera import Camera, look_at
from go_core.coarse.hull import points_to_gaussians, visual_hull
from go_core.errors import EmptyHullError

pytestmark = pytest.mark.usefixtures("single_thread")  # small tensors: one thread is faster


def sphere_mask(cam: Camera, center: np.ndarray, r: float, ss: int = 4) -> np.ndarray:
    """Analytic silhouette of a sphere: fractional pixel coverage by supersampled ray-sphere tests."""
    h, w = cam.height, cam.width
    ys, xs = np.meshgrid((np.arange(h * ss) + 0.5) / ss, (np.arange(w * ss) + 0.5) / ss, indexing="ij")
    pix = np.stack([xs, ys, np.ones_like(xs)], -1).reshape(-1, 3)
    dirs = (pix @ np.linalg.inv(cam.K).T) @ cam.world_to_cam[:3, :3]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    oc = center - cam.center
    t = dirs @ oc
    inside = ((oc @ oc) - t**2 <= r * r) & (t > 0)
    return inside.reshape(h * ss, w * ss).astype(np.float32).reshape(h, ss, w, ss).mean((1, 3))


def axis_cameras(dist: float, r: float, size: int = 128, offset=(0.0, 0.0, 0.0)) -> list[Camera]:
    """Three nearly orthographic cameras along +x, +y, +z looking at ``offset``; the sphere fills ~80%."""
    f = size * 0.4 / (r / dist)
    K = np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]])
    o = np.asarray(offset, float)
    setups = [((1, 0, 0), (0, 0, 1)), ((0, 1, 0), (0, 0, 1)), ((0, 0, 1), (0, 1, 0))]
    return [
        look_at(f"c{i}", o + dist * np.array(p, float), o, np.array(up, float), K, size, size)
        for i, (p, up) in enumerate(setups)
    ]


@pytest.mark.parametrize(
    "r,offset", [(1.0, (0.0, 0.0, 0.0)), (1e4, (3e5, -2e5, 1e5)), (1e-3, (0.01, 0.0, 0.0))]
)
def test_hull_of_sphere_from_three_axis_views_is_the_tricylinder(r, offset):
    """Three orthographic views of a sphere carve a Steinmetz tricylinder: V = 8(2 - √2) r³. Cameras are far
    away (200 r) so the cones are nearly cylinders; scenes with huge or tiny coordinates work the same."""
    cams = axis_cameras(200.0 * r, r, offset=offset)
    masks = [sphere_mask(c, np.asarray(offset, float), r) for c in cams]
    res = visual_hull(cams, masks, all_but_one=False, num_points=5000, seed=0)
    analytic = 8.0 * (2.0 - np.sqrt(2.0)) * r**3
    assert res.volume == pytest.approx(analytic, rel=0.05)
    assert len(res.points) == 5000
    rel = (res.points - np.asarray(offset)) / r
    assert np.abs(rel).max() <= 1.0 + 0.02  # every point inside the [-r, r]³ bounding cube
    assert np.all(np.sum(rel**2 > 1.0 + 0.02, axis=1) <= 1)  # outside at most one cylinder? none, in fact
    for axis in range(3):  # inside each of the three cylinders
        other = [k for k in range(3) if k != axis]
        assert np.all((rel[:, other] ** 2).sum(1) <= 1.0 + 0.03)


def test_all_but_one_view_keeps_a_larger_region():
    cams = axis_cameras(200.0, 1.0)
    masks = [sphere_mask(c, np.zeros(3), 1.0) for c in cams]
    full = visual_hull(cams, masks, all_but_one=False, num_points=2000, seed=1)
    loose = visual_hull(cams, masks, num_points=2000, seed=1, all_but_one=True)
    assert loose.min_views == 2 and full.min_views == 3
    assert loose.volume > 1.2 * full.volume


def test_empty_hull_raises_a_clear_error():
    cams = axis_cameras(200.0, 1.0)
    masks = [sphere_mask(c, np.zeros(3), 1.0) for c in cams]
    # move one view's silhouette to a corner: it no longer overlaps the others in 3D
    masks[2] = np.zeros_like(masks[2])
    masks[2][:10, :10] = 1.0
    with pytest.raises(EmptyHullError, match="pose is probably wrong"):
        visual_hull(cams, masks, all_but_one=False, num_points=100)
    with pytest.raises(EmptyHullError):
        visual_hull(cams, [np.zeros_like(m) for m in masks], all_but_one=False, num_points=100)


def test_empty_hull_names_the_camera_that_looks_away():
    """Four views of a sphere; one camera turned to look away from it: the error names that camera."""
    cams = axis_cameras(200.0, 1.0) + [
        look_at(
            "c3",
            np.array([-200.0, 0, 0]),
            np.zeros(3),
            np.array([0, 0, 1.0]),
            axis_cameras(200.0, 1.0)[0].K,
            128,
            128,
        )
    ]
    masks = [sphere_mask(c, np.zeros(3), 1.0) for c in cams]
    away = cams[1]
    cams[1] = look_at(
        "c1", away.center, away.center + (away.center - np.zeros(3)), np.array([0, 0, 1.0]), away.K, 128, 128
    )
    with pytest.raises(EmptyHullError, match="mask cone misses .* camera 'c1' the region"):
        visual_hull(cams, masks, all_but_one=False, num_points=100)


def test_colours_come_from_the_views_that_see_the_point_and_gaussians_follow():
    cams = axis_cameras(200.0, 1.0, size=64)
    masks = [sphere_mask(c, np.zeros(3), 1.0, ss=2) for c in cams]
    colours = [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)]
    images = [np.broadcast_to(np.asarray(c, np.float32), (64, 64, 3)).copy() for c in colours]
    res = visual_hull(cams, masks, images, all_but_one=False, num_points=500, seed=0)
    assert np.allclose(res.colors, 1.0 / 3.0, atol=1e-5)  # every hull point is seen by all three views
    g = points_to_gaussians(res.points, res.colors, opacity=0.1)
    assert len(g) == 500
    assert np.allclose(g.opacities().numpy(), 0.1, atol=1e-6)
    assert np.allclose(g.quats.numpy(), [1, 0, 0, 0])
    from scipy.spatial import cKDTree

    d, _ = cKDTree(res.points).query(res.points, k=4)
    assert np.allclose(g.scales().numpy()[:, 0], d[:, 1:].mean(1), rtol=1e-5)
    from go_core.gaussians import sh0_to_rgb

    assert np.allclose(sh0_to_rgb(g.sh[:, 0]).numpy(), 1.0 / 3.0, atol=1e-5)
