"""Geometry metrics against hand-computed values on small meshes, and the independent silhouette."""

from __future__ import annotations

import numpy as np
import pytest

from go_core.mesh.types import TriMesh
from go_core.metrics.geometry import bounding_radius, geometry_metrics, silhouette_iou
from tests._synthetic_depth import ring_cameras, sphere_depth


def _rectangle(x1: float, y1: float, z: float = 0.0) -> TriMesh:
    """The rectangle [0, x1] x [0, y1] at height z, two triangles."""
    v = np.array([[0, 0, z], [x1, 0, z], [x1, y1, z], [0, y1, z]], np.float64)
    return TriMesh(v, np.array([[0, 1, 2], [0, 2, 3]], np.int64))


N = 200_000  # samples: mean spacing ~0.003 on these unit-size surfaces, the distances' sampling floor


def test_half_covered_rectangle():
    """Prediction = the left half of the truth (same plane). By hand: accuracy 0; completeness = mean over
    the truth of its distance to [0,1]^2 = (1/2)(0) + (1/2)(mean of x-1 over [1,2]) = 0.25; Chamfer 0.125.
    r = |(1, 0.5)| = 1.118; recall@τ = 1/2 + (1/2)(τ r) (the strip within τ r of the edge); precision 1."""
    res = geometry_metrics(_rectangle(1, 1), _rectangle(2, 1), count=N, seed=0)
    r = np.hypot(1.0, 0.5)
    assert res["gt_radius"] == pytest.approx(r)
    assert res["accuracy"] < 0.003
    assert res["completeness"] == pytest.approx(0.25, abs=0.003)
    assert res["chamfer_l1"] == pytest.approx(0.125, abs=0.003)
    for tau, tag in ((0.01, "1pct"), (0.02, "2pct")):
        recall = 0.5 + 0.5 * tau * r
        assert res[f"precision_{tag}"] > 0.995
        assert res[f"recall_{tag}"] == pytest.approx(recall, abs=0.005)
        assert res[f"fscore_{tag}"] == pytest.approx(2 * recall / (1 + recall), abs=0.005)
    assert res["normal_consistency"] == pytest.approx(1.0)


def test_parallel_and_perpendicular_squares():
    """Two unit squares 0.05 apart: every distance is 0.05 (up to the sampling floor), so Chamfer 0.05 and
    F = 0 at 1% and 2% of r = 0.707 (0.007, 0.014 < 0.05), normals agree; a square standing on the edge
    x = 0 of the other has normal consistency 0."""
    res = geometry_metrics(_rectangle(1, 1, 0.05), _rectangle(1, 1), count=N, seed=1)
    assert bounding_radius(_rectangle(1, 1)) == pytest.approx(np.sqrt(0.5))
    assert res["chamfer_l1"] == pytest.approx(0.05, abs=0.001)
    assert res["fscore_1pct"] == 0.0 and res["fscore_2pct"] == 0.0
    assert res["normal_consistency"] == pytest.approx(1.0)
    wall = TriMesh(np.array([[0, 0, 0], [0, 1, 0], [0, 1, 1], [0, 0, 1.0]]), np.array([[0, 1, 2], [0, 2, 3]]))
    assert geometry_metrics(wall, _rectangle(1, 1), count=20_000, seed=2)["normal_consistency"] < 1e-9


def test_metrics_are_deterministic_for_a_seed():
    a = geometry_metrics(_rectangle(1, 1, 0.01), _rectangle(2, 1), count=5000, seed=3)
    b = geometry_metrics(_rectangle(1, 1, 0.01), _rectangle(2, 1), count=5000, seed=3)
    assert a == b


def test_threaded_queries_equal_a_brute_force_reference():
    """The nearest-sample queries on two threads give the figures of one thread, and both equal a
    brute-force float64 search over every pair (accuracy, completeness, precision at 1% of r = 10)."""
    from go_core.metrics.geometry import compare_samples

    rng = np.random.default_rng(5)
    pred = (rng.normal(size=(1500, 3)), rng.normal(size=(1500, 3)))
    gt = (rng.normal(size=(1200, 3)) * 0.9, rng.normal(size=(1200, 3)))
    gt = (gt[0], gt[1] / np.linalg.norm(gt[1], axis=1, keepdims=True))
    pred = (pred[0], pred[1] / np.linalg.norm(pred[1], axis=1, keepdims=True))
    one, two = compare_samples(pred, gt, 10.0, workers=1), compare_samples(pred, gt, 10.0, workers=2)
    assert one == two
    dist = np.linalg.norm(pred[0][:, None, :] - gt[0][None, :, :], axis=2)
    assert two["accuracy"] == pytest.approx(dist.min(1).mean(), rel=1e-12)
    assert two["completeness"] == pytest.approx(dist.min(0).mean(), rel=1e-12)
    share = (dist.min(1) < 0.1).mean()  # 1% of r = 10
    assert 0.05 < share < 0.95 and two["precision_1pct"] == pytest.approx(share)


def test_silhouette_of_a_sphere_mesh_matches_its_analytic_mask():
    from go_core.mesh.surface import marching_cubes

    n = 96
    x = np.linspace(-1.0, 1.0, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    mesh = marching_cubes(np.sqrt(X**2 + Y**2 + Z**2) - 0.8, np.full(3, -1.0), x[1] - x[0])
    for cam in ring_cameras(3, size=96):
        mask = sphere_depth(cam, 0.8)[1]
        assert silhouette_iou(mesh, cam, mask) > 0.985
        assert silhouette_iou(mesh, cam, np.zeros_like(mask)) == 0.0


def test_sliding_midpoint_tree_gives_the_default_trees_exact_neighbours():
    """The eval's faster tree (sliding-midpoint splits) returns the default cKDTree's nearest distances
    and samples to the bit, on samples of flat faces (where the default tree is slow) queried from off
    them; so the metrics do not depend on which tree searched."""
    from scipy.spatial import cKDTree

    from go_core.metrics.geometry import nearest_sample_tree

    rng = np.random.default_rng(11)
    faces = []
    for axis in range(3):  # the six faces of a box, 4000 samples each
        for side in (-1.0, 1.0):
            pts = rng.uniform(-1, 1, size=(4000, 3))
            pts[:, axis] = side
            faces.append(pts)
    box = np.concatenate(faces)
    queries = rng.normal(size=(6000, 3)) * 0.8
    d_ref, i_ref = cKDTree(box).query(queries)
    d, i = nearest_sample_tree(box).query(queries, workers=2)
    assert np.array_equal(d, d_ref) and np.array_equal(i, i_ref)
