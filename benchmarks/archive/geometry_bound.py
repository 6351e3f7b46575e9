"""What the silhouettes allow at best (issue 35): the Chamfer-L1 of shapes that any reconstruction from
silhouettes alone would give, against the visual hull of the four training views (the check's baseline).

Per dev scene, scored against the ground-truth mesh like the eval step (``geometry_metrics``, ``--samples``
per surface, seed 0):

* ``hull_4``: the mesh step's hull: the four training masks, ``hull_mesh`` at ``--resolution``;
* ``hull_all``: the visual hull of the *true* object from ``--views`` cameras on a Fibonacci sphere around
  its bounding-box centre (the first training camera's intrinsics, far enough that the truth's bounding
  sphere fills at most 90% of the narrower field of view, so no view crops it), each mask the truth's own
  silhouette (``silhouette``, OpenCV fill): silhouettes from every direction. A concavity that no
  silhouette reveals (a bowl's cavity, a can's recessed lid) stays filled;
* ``convex``: the truth's convex hull (scipy): a looser bound of the same kind, which also keeps the
  concavities that side silhouettes do reveal (a can's beads).

What only photo-consistency or a shape prior can place is the truth's surface inside ``hull_all``.
``concave`` says how much of the truth that is: the share of ``--probe`` area samples farther than
``--concave-at`` (2%) of its radius from ``hull_all`` (twice F@1%'s threshold, so that the hull's own
error of under a voxel does not count). It also says how much of it the training photos see, by at least
1 and at least 2 views. A sample is seen by a view when it projects into the image and the segment from it
(lifted off its face towards the camera) to the camera centre crosses no triangle of the truth
(Moller-Trumbore in numpy). Where ``hull_all`` scores above 0.5x ``hull_4``, the issue's check (a final
mesh at most 0.5x the hull's Chamfer) cannot be met without that surface.

    python benchmarks/archive/geometry_bound.py --data ../shared/data/dev \\
        --scenes alphabet_soup basket milk plate white_bowl --out benchmarks/results/geometry_bound.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from _machine import code_version  # benchmarks/ is on sys.path as a script

from go_core.camera import Camera, fit_ellipse, look_at
from go_core.mesh.files import read_mesh_npz
from go_core.mesh.hull_mesh import hull_mesh
from go_core.mesh.types import TriMesh
from go_core.mesh.views import fibonacci_directions
from go_core.metrics.geometry import bounding_radius, geometry_metrics, silhouette
from go_core.scene.loader import load_scene

KEYS = ("chamfer_l1", "accuracy", "completeness", "fscore_1pct", "fscore_2pct")


def convex_hull(mesh: TriMesh) -> TriMesh:
    """The convex hull of ``mesh``'s vertices as a triangle mesh."""
    from scipy.spatial import ConvexHull

    hull = ConvexHull(mesh.vertices)
    return TriMesh(np.asarray(mesh.vertices, np.float64), hull.simplices.astype(np.int64))


def framing_cameras(truth: TriMesh, train_cameras: list[Camera], views: int) -> list[Camera]:
    """``views`` cameras on a Fibonacci sphere around ``truth`` that each see all of it (docstring)."""
    like = train_cameras[0]
    centre = 0.5 * (truth.vertices.min(0) + truth.vertices.max(0))
    radius = bounding_radius(truth)  # about ``centre``, the bounding box's centre
    half_fov = np.arctan(0.5 * min(like.width, like.height) / float(np.asarray(like.K)[0, 0]))
    distance = radius / np.sin(0.9 * half_fov)
    up = fit_ellipse(train_cameras).normal
    cams = [
        look_at(f"all_{k:03d}", centre + distance * d, centre, up, like.K, like.width, like.height)
        for k, d in enumerate(fibonacci_directions(views))
    ]
    for cam in cams:
        uv, z = cam.project(truth.vertices)
        inside = (z > 0).all() and (uv >= 0).all() and (uv[:, 0] < cam.width).all()
        if not (inside and (uv[:, 1] < cam.height).all()):
            raise RuntimeError(f"{cam.name} crops the ground-truth mesh")
    return cams


def all_directions_hull(truth: TriMesh, train_cameras: list[Camera], views: int, resolution: int) -> TriMesh:
    """The visual hull of ``truth`` carved by its own silhouettes from ``views`` framing cameras."""
    cams = framing_cameras(truth, train_cameras, views)
    masks = [silhouette(truth, c).astype(np.float32) for c in cams]
    return hull_mesh(cams, masks, resolution)


def occluded(points: np.ndarray, origin: np.ndarray, tris: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Per point [N,3]: whether the segment from it to ``origin`` crosses any triangle of ``tris`` [F,3,3]
    (Moller-Trumbore; hits within ``eps`` of either end are ignored)."""
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    hit = np.zeros(len(points), bool)
    for i, p in enumerate(points):
        d = origin - p
        h = np.cross(d, e2)
        a = np.einsum("ij,ij->i", e1, h)
        ok = np.abs(a) > 1e-12
        f = np.where(ok, 1.0 / np.where(ok, a, 1.0), 0.0)
        s = p - tris[:, 0]
        u = f * np.einsum("ij,ij->i", s, h)
        q = np.cross(s, e1)
        v = f * (q @ d)
        t = f * np.einsum("ij,ij->i", e2, q)
        hit[i] = bool((ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > eps) & (t < 1 - eps)).any())
    return hit


def views_seeing(points: np.ndarray, normals: np.ndarray, truth: TriMesh, cams: list[Camera]) -> np.ndarray:
    """Per point: how many of ``cams`` see it from either side of its face (module docstring)."""
    tris = np.asarray(truth.vertices, np.float64)[truth.faces]
    count = np.zeros(len(points), np.int64)
    for cam in cams:
        uv, z = cam.project(points)
        inside = (
            (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        )
        side = np.sign(np.einsum("ij,ij->i", normals, cam.center - points))[:, None]
        todo = np.nonzero(inside & (side[:, 0] != 0))[0]
        lifted = points[todo] + 1e-5 * side[todo] * normals[todo]
        count[todo] += ~occluded(lifted, cam.center, tris)
    return count


def concave_share(
    truth: TriMesh, hull_all: TriMesh, cams: list[Camera], probe: int, at: float = 0.02
) -> dict:
    """How much of ``truth`` lies inside the all-directions hull, and how much of that the ``cams`` see."""
    from scipy.spatial import cKDTree

    from go_core.metrics.geometry import sample_surface
    from go_core.seeding import numpy_rng

    pts, nrm = sample_surface(truth, probe, numpy_rng(0, "geometry_bound", "probe"))
    # the face normals' sign is the mesh's winding; a sample is seen from the side a camera is on
    dist, _ = cKDTree(sample_surface(hull_all, 200_000, numpy_rng(0, "geometry_bound", "hull"))[0]).query(pts)
    concave = dist > at * bounding_radius(truth)
    views = views_seeing(pts, nrm, truth, cams)
    out = {"probe_samples": probe, "at": at, "share_of_truth": round(float(concave.mean()), 4)}
    for k in (1, 2):
        for name, part in (("concave", concave), ("elsewhere", ~concave)):
            out[f"seen_by_{k}_{name}"] = round(float((views[part] >= k).mean()), 4) if part.any() else None
    return out


def measure(scene_dir: Path, views: int, resolution: int, samples: int, probe: int, at: float) -> dict:
    scene = load_scene(scene_dir)
    truth = read_mesh_npz(scene_dir / "mesh_world.npz")
    cams, masks = scene.train_cameras, [v.mask for v in scene.train]
    t0 = time.perf_counter()
    shapes = {
        "hull_4": hull_mesh(cams, masks, resolution),
        "hull_all": all_directions_hull(truth, cams, views, resolution),
        "convex": convex_hull(truth),
    }
    out: dict = {}
    for name, mesh in shapes.items():
        res = geometry_metrics(mesh, truth, samples, 0)
        out[name] = {k: round(float(res[k]), 4) for k in KEYS}
    for name in ("hull_all", "convex"):
        out[name]["ratio_to_hull_4"] = round(out[name]["chamfer_l1"] / out["hull_4"]["chamfer_l1"], 3)
    out["concave"] = concave_share(truth, shapes["hull_all"], cams, probe, at)
    out["seconds"] = round(time.perf_counter() - t0, 1)
    return out


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--scenes", nargs="+", required=True)
    ap.add_argument("--views", type=int, default=200)
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--probe", type=int, default=1000)
    ap.add_argument("--concave-at", type=float, default=0.02)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    result = {
        "settings": {
            "views": args.views,
            "resolution": args.resolution,
            "samples": args.samples,
            "seed": 0,
            "probe": args.probe,
            "concave_at": args.concave_at,
        },
        "command": f"python benchmarks/archive/geometry_bound.py {' '.join(argv)} (code {code_version()})",
        "scenes": {},
    }
    for name in args.scenes:
        result["scenes"][name] = measure(
            args.data / name, args.views, args.resolution, args.samples, args.probe, args.concave_at
        )
        print(name, json.dumps(result["scenes"][name]), flush=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
