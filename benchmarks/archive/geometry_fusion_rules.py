"""Ablation of the mesh step's fusion rules on the dev scenes' cached coarse models (docs/geometry.md).

Per scene the fusion views (24 ellipse + 40 sphere, 256 px) are rendered once: expected depth, median
depth, alpha and the free depth (where the opacity reaches 0.05); each variant ``DEPTH_CARVE_CLIP`` is
then fused on the mesh step's 160³ grid (truncation 3 voxels) and scored against the ground truth with
``--samples`` points per surface (seed 0):

* DEPTH: ``exp`` (expected) or ``med`` (median);
* CARVE: a number c (a pixel with alpha ≤ c carves its whole ray; 0.5 was the first version's rule) or
  ``free`` (carve_alpha 0.05 with the free depth: a ray is empty only up to where its opacity reaches it);
* CLIP: ``clip`` (intersect with the visual hull) or ``none``; ``hull`` alone scores the hull's mesh.

Coarse models come from ``benchmarks/geometry_dev.py --stage train`` (``--cache``). Results accumulate in
``--out`` (a variant already there is not rerun).

    python benchmarks/archive/geometry_fusion_rules.py milk exp_0.5_none,med_free_clip,hull
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from go_core.coarse.hull import hull_bounds
from go_core.gaussians import Gaussians
from go_core.mesh.extract import clip_to_hull, render_maps
from go_core.mesh.files import read_mesh_npz
from go_core.mesh.hull_mesh import hull_mesh
from go_core.mesh.surface import largest_component, marching_cubes
from go_core.mesh.tsdf import FusionRule, View, VoxelGrid, fuse_narrow_band
from go_core.mesh.views import fusion_cameras
from go_core.metrics.geometry import geometry_metrics
from go_core.scene.loader import load_scene

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/ (_lib.coarse), from archive/
from _lib.coarse import DEV  # noqa: E402

KEYS = ("chamfer_l1", "accuracy", "completeness", "fscore_1pct", "fscore_2pct", "normal_consistency")


def maps(scene, cache: Path, name: str, cameras) -> dict:
    """Expected / median / free depth and alpha of every fusion view, rendered once per scene."""
    path = cache / f"{name}_fusion_maps.npz"
    if path.is_file():
        return dict(np.load(path))
    g = Gaussians.load(cache / name / "coarse_gaussians.npz").to(dtype=torch.float32)
    exp = list(render_maps(g, cameras, "auto", 8, "expected", 0.05))
    med = list(render_maps(g, cameras, "auto", 8, "median", 0.05))
    out = {
        "expected": np.stack([m[1] for m in exp]),
        "median": np.stack([m[1] for m in med]),
        "alpha": np.stack([m[2] for m in exp]),
        "free": np.stack([m[4] for m in exp]),
    }
    np.savez_compressed(path, **out)
    return out


def variant_mesh(variant: str, scene, m: dict, cameras):
    """The mesh of one variant (module docstring)."""
    train, masks = scene.train_cameras, [v.mask for v in scene.train]
    if variant == "hull":
        return hull_mesh(train, masks, 128)
    depth, carve, clip = variant.split("_")
    d = m["median" if depth == "med" else "expected"]
    free = carve == "free"
    views = [
        View(c, d[i], m["alpha"][i], None, m["free"][i] if free else None) for i, c in enumerate(cameras)
    ]
    box = hull_bounds(train, masks, min_views=len(train))
    grid = VoxelGrid.around(box[0], box[1], 160)
    rule = FusionRule(3 * grid.voxel, 0.5, 0.05 if free else float(carve), 0.0)
    field = fuse_narrow_band(grid, views, rule).field
    if clip == "clip":
        field = clip_to_hull(field, grid, train, masks)
    return largest_component(marching_cubes(field, grid.origin, grid.voxel))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("variants", help="comma-separated DEPTH_CARVE_CLIP or hull")
    ap.add_argument("--data", type=Path, default=DEV)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/geometry_dev"))
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/geometry_fusion_rules.json"))
    args = ap.parse_args()
    scene = load_scene(args.data / args.scene)
    cameras = fusion_cameras(scene.train_cameras, 24, 40, 256)
    m = maps(scene, args.cache, args.scene, cameras)
    gt = read_mesh_npz(args.data / args.scene / "mesh_world.npz")
    fresh = {"samples": args.samples, "scenes": {}}
    results = json.loads(args.out.read_text()) if args.out.is_file() else fresh
    done = results["scenes"].setdefault(args.scene, {})
    for variant in args.variants.split(","):
        if variant in done:
            continue
        t0 = time.perf_counter()
        mesh = variant_mesh(variant, scene, m, cameras)
        t1 = time.perf_counter()
        res = geometry_metrics(mesh, gt, args.samples, 0)
        row = {k: round(res[k], 4) for k in KEYS}
        row.update(volume=round(mesh.volume(), 3), mesh_s=round(t1 - t0, 1))
        row["metric_s"] = round(time.perf_counter() - t1, 1)
        done[variant] = row
        print(args.scene, variant, row, flush=True)
        args.out.write_text(json.dumps(results, indent=1, sort_keys=True))


if __name__ == "__main__":
    main()
