"""go_core.metrics.error_split: mesh depth maps against ray-sphere intersections, occlusion, seen/unseen
against the analytic visibility of a sphere, and the error split adding up to the whole image's."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from go_core.camera import look_at
from go_core.mesh.types import TriMesh
from go_core.metrics.error_split import (
    REGIONS,
    SeenSurface,
    depth_map,
    face_map,
    split_errors,
    summarise,
    surface_points,
)

SIZE = 96
K = np.array([[110.0, 0.0, SIZE / 2], [0.0, 110.0, SIZE / 2], [0.0, 0.0, 1.0]])


def uv_sphere(radius: float = 1.0, rings: int = 96, segments: int = 192) -> TriMesh:
    """A closed UV sphere about the origin, faces counter-clockwise seen from outside."""
    theta = np.linspace(0.0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    verts = radius * np.concatenate([[[0, 0, 1.0]], ring, [[0, 0, -1.0]]])
    faces = []
    idx = lambda i, j: 1 + i * segments + (j % segments)  # noqa: E731
    for j in range(segments):
        faces.append([0, idx(0, j), idx(0, j + 1)])
        faces.append([len(verts) - 1, idx(rings - 2, j + 1), idx(rings - 2, j)])
    for i in range(rings - 2):
        for j in range(segments):
            a, b, c, d = idx(i, j), idx(i, j + 1), idx(i + 1, j), idx(i + 1, j + 1)
            faces += [[a, c, b], [b, c, d]]
    return TriMesh(verts, np.asarray(faces, np.int64))


def camera_at(direction, distance: float = 4.0, name: str = "cam"):
    d = np.asarray(direction, np.float64)
    return look_at(name, distance * d / np.linalg.norm(d), np.zeros(3), np.array([0, 0, 1.0]), K, SIZE, SIZE)


def ray_sphere_depth(camera, radius: float = 1.0) -> np.ndarray:
    """Analytic camera-frame depth of the sphere at each pixel centre (inf where the ray misses)."""
    ys, xs = np.mgrid[0:SIZE, 0:SIZE]
    pix = np.stack([xs + 0.5, ys + 0.5, np.ones_like(xs, dtype=float)], -1).reshape(-1, 3)
    rays = pix @ np.linalg.inv(camera.K).T  # z = 1
    R = camera.world_to_cam[:3, :3]
    dirs, origin = rays @ R, camera.center  # world directions (not unit), origin
    a = (dirs**2).sum(1)
    b = 2 * dirs @ origin
    c = origin @ origin - radius**2
    disc = b * b - 4 * a * c
    t = np.where(disc >= 0, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), np.inf)
    return t.reshape(SIZE, SIZE)  # the ray's z component is 1 in the camera frame: t is the depth


def test_depth_map_matches_the_ray_sphere_intersection():
    sphere, cam = uv_sphere(), camera_at([1.0, 0.3, 0.2])
    got, want = depth_map(sphere, cam), ray_sphere_depth(cam)
    both = np.isfinite(got) & np.isfinite(want)
    # the silhouettes differ only on the rim, where the inscribed mesh misses a pixel centre
    rim = np.isfinite(want) & (cv2.erode(np.isfinite(want).astype(np.uint8), np.ones((3, 3), np.uint8)) == 0)
    assert not (np.isfinite(got) & ~np.isfinite(want)).any()
    assert not (np.isfinite(want) & ~np.isfinite(got) & ~rim).any()
    # facets lie inside the sphere by at most the sagitta r (1 - cos(pi / rings)) ~ 5e-4
    interior = both & (want < 3.6)  # away from the grazing rim
    assert np.abs(got[interior] - want[interior]).max() < 2e-3
    assert (got[both] >= want[both] - 1e-9).mean() > 0.99  # inscribed: never in front of the sphere


def test_the_nearer_of_two_overlapping_squares_wins():
    def square(z: float) -> np.ndarray:
        return np.array([[-1, -1, z], [1, -1, z], [1, 1, z], [-1, 1, z]], np.float64)

    verts = np.concatenate([square(0.0), square(1.0)])  # the second is nearer to a camera on +z
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    mesh = TriMesh(verts, faces)
    cam = look_at("top", np.array([0, 0, 4.0]), np.zeros(3), np.array([0, 1.0, 0]), K, SIZE, SIZE)
    fm = face_map(mesh, cam)
    assert set(np.unique(fm[fm >= 0])) <= {2, 3}  # only the near square's faces are seen
    depth = depth_map(mesh, cam)
    assert np.allclose(depth[fm >= 0], 3.0)


def _analytic_seen_share(test_cam, train_cams) -> tuple[float, np.ndarray]:
    """Share of the test view's sphere pixels whose surface point a training camera sees (convex: the
    point's normal faces the camera), from the exact ray-sphere points."""
    points, covered = surface_points(test_cam, ray_sphere_depth(test_cam))
    seen = np.zeros(len(points), bool)
    for cam in train_cams:
        seen |= np.einsum("ij,ij->i", points, cam.center - points) > 0  # normal = point on a unit sphere
    return float(seen.mean()), covered


@pytest.mark.parametrize(
    ("train_dirs", "low", "high"),
    [
        ([[1.0, 0.0, 0.0]], 0.98, 1.0),  # the test camera is a training camera: everything seen
        ([[-1.0, 0.0, 0.0]], 0.0, 0.02),  # the opposite side: nothing seen
        ([[0.0, 1.0, 0.0]], None, None),  # 90 degrees away: compared with the analytic share
        ([[0.5, 1.0, 0.3]], None, None),
        ([[-0.3, 1.0, 0.5]], None, None),
        ([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]], None, None),
    ],
)
def test_seen_surface_matches_the_analytic_visibility_of_a_sphere(train_dirs, low, high):
    sphere = uv_sphere()
    test = camera_at([1.0, 0.0, 0.0], name="test")
    train = [camera_at(d, name=f"train{i}") for i, d in enumerate(train_dirs)]
    regions = SeenSurface(sphere, train).regions(test, np.isfinite(depth_map(sphere, test)).astype(float))
    inside = regions["seen"] | regions["unseen"]
    share = regions["seen"].sum() / inside.sum()
    want, _ = _analytic_seen_share(test, train)
    if low is not None:
        assert low <= share <= high, share
    assert abs(share - want) < 0.01 * len(train), (share, want)  # each rim: a band within tolerance
    assert not (regions["outside"] & inside).any()


def test_the_split_adds_up_to_the_whole_image():
    rng = np.random.default_rng(0)
    gt, pred = rng.random((SIZE, SIZE, 3)), rng.random((SIZE, SIZE, 3))
    ys, xs = np.mgrid[0:SIZE, 0:SIZE]
    inside = (xs - 48) ** 2 + (ys - 48) ** 2 < 30**2
    regions = {"outside": ~inside, "seen": inside & (xs < 48), "unseen": inside & (xs >= 48)}
    per_view = [split_errors(pred, gt, regions), split_errors(gt, gt, regions)]
    total_sse = ((pred - gt) ** 2).mean(-1).sum()
    assert sum(per_view[0][r]["sse"] for r in REGIONS) == pytest.approx(total_sse, rel=1e-12)
    s = summarise(per_view)
    assert sum(s[r]["error_share"] for r in REGIONS) == pytest.approx(1.0)
    assert sum(s[r]["pixel_share"] for r in REGIONS) == pytest.approx(1.0)
    whole_mse = total_sse / (2 * SIZE * SIZE)  # the second view is exact
    for r in REGIONS:
        region_sse = ((pred - gt) ** 2).mean(-1)[regions[r]].sum()
        assert s[r]["mse"] == pytest.approx(region_sse / (2 * regions[r].sum()))
        assert s[r]["psnr_if_rest_exact"] == pytest.approx(-10 * np.log10(region_sse / (2 * SIZE * SIZE)))
    assert -10 * np.log10(whole_mse) < min(s[r]["psnr_if_rest_exact"] for r in REGIONS)
