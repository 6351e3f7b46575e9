"""benchmarks/geometry_bound.py on a cup (a unit cube without its lid, with a floor halfway down): the
silhouettes from every direction give the closed cube, the floor is the concave part, and a camera sees the
floor from straight above but not from the side, where the walls hide it."""

from __future__ import annotations

import numpy as np
import pytest
from _benchmark_module import benchmark_module
from _ellipsoids import SIZE, ring_cameras

from go_core.camera import look_at
from go_core.mesh.types import TriMesh
from go_core.metrics.geometry import geometry_metrics

HALF = 0.5
QUADS = {  # corners index x, y, z in {-HALF, HALF} as bits 2, 1, 0
    "bottom": (0, 2, 6, 4),
    "x-": (0, 1, 3, 2),
    "x+": (4, 6, 7, 5),
    "y-": (0, 4, 5, 1),
    "y+": (2, 3, 7, 6),
    "top": (1, 5, 7, 3),
}


def _box(faces: list[str], floor: bool = False) -> TriMesh:
    corners = [[x, y, z] for x in (-HALF, HALF) for y in (-HALF, HALF) for z in (-HALF, HALF)]
    tris = [t for name in faces for a, b, c, d in [QUADS[name]] for t in ((a, b, c), (a, c, d))]
    if floor:  # a square at z = 0 spanning the inside
        base = len(corners)
        corners += [[x, y, 0.0] for x in (-HALF, HALF) for y in (-HALF, HALF)]
        tris += [(base, base + 1, base + 3), (base, base + 3, base + 2)]
    return TriMesh(np.array(corners, np.float64), np.array(tris, np.int64))


@pytest.fixture(scope="module")
def bench():
    return benchmark_module("geometry_bound")


def _camera(position, up=(0.0, 0.0, 1.0)):
    like = ring_cameras(1)[0]
    return look_at(
        "probe", np.asarray(position, float), np.zeros(3), np.asarray(up, float), like.K, SIZE, SIZE
    )


ABOVE, SIDE = ([0.0, 0.0, 4.0], (0.0, 1.0, 0.0)), ([4.0, 0.0, 0.0],)


def test_a_segment_through_a_wall_is_occluded(bench):
    cube = _box(list(QUADS))
    tris = cube.vertices[cube.faces]
    eye = np.array([3.0, 0.2, 0.1])
    points = np.array([[0.0, 0.0, 0.0], [-0.4, 0.1, 0.2], [0.9, 0.0, 0.0], [HALF + 1e-4, 0.1, 0.1]])
    assert bench.occluded(points, eye, tris).tolist() == [True, True, False, False]


def test_the_floor_of_a_cup_is_seen_from_above_not_from_the_side(bench):
    cup = _box(["bottom", "x-", "x+", "y-", "y+"], floor=True)
    pts = np.array([[0.1, -0.2, 0.0], [-0.3, 0.25, 0.0]])  # on the floor
    normals = np.tile([0.0, 0.0, 1.0], (2, 1))
    above, side = _camera(*ABOVE), _camera(*SIDE)
    assert bench.views_seeing(pts, normals, cup, [above]).tolist() == [1, 1]
    assert bench.views_seeing(pts, normals, cup, [side]).tolist() == [0, 0]
    assert bench.views_seeing(pts, normals, cup, [above, side, above]).tolist() == [2, 2]


def test_silhouettes_from_every_direction_close_the_cup(bench):
    cup, cube = _box(["bottom", "x-", "x+", "y-", "y+"], floor=True), _box(list(QUADS))
    cams = [c.scaled(4.0) for c in ring_cameras(4)]  # 256 px: a pixel ~0.011 at the framing distance
    hull = bench.all_directions_hull(cup, cams, views=100, resolution=64)  # fewer views: walls bulge out
    voxel = 2 * HALF / 64
    assert geometry_metrics(hull, cube, 20_000)["chamfer_l1"] < 1.5 * voxel  # the lid is back
    share = bench.concave_share(cup, hull, [_camera(*ABOVE)], probe=3000)
    # the floor: 1 of the cup's 6 unit squares, less its band within 2% of r (0.0173) of the walls
    assert share["share_of_truth"] == pytest.approx(1 / 6 * (1 - 2 * 0.0173) ** 2, abs=0.01)
    assert share["seen_by_1_concave"] == 1.0 and share["seen_by_2_concave"] == 0.0
