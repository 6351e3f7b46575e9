"""The TSDF truncation, chosen by measurement on analytic shapes (never on the dev or reserved objects):
a sphere (r 0.8) and a cube (half side 0.6) seen by 24 cameras (8 on a ring, 16 on a sphere) at 96 px,
depth maps exact or with Gaussian noise of 0.5 and 1 voxel (the rendered depth of Gaussians is not exact),
fused on a 64^3 grid with the truncation 1.5 / 3 / 5 / 8 voxels; Chamfer-L1 and F@1% against the analytic
surface (go_core.metrics.geometry, 100 000 samples, seed 0).

    python benchmarks/archive/tsdf_truncation.py --out benchmarks/results/tsdf_truncation.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from go_core.mesh.surface import largest_component, marching_cubes  # noqa: E402
from go_core.mesh.tsdf import FusionRule, View, VoxelGrid, fuse_narrow_band  # noqa: E402
from go_core.metrics.geometry import geometry_metrics  # noqa: E402
from go_core.seeding import numpy_rng  # noqa: E402
from tests._synthetic_depth import (  # noqa: E402
    box_mesh,
    cube_depth,
    ring_cameras,
    sphere_cameras_around,
    sphere_depth,
)

TRUNCATIONS = (1.5, 3.0, 5.0, 8.0)
NOISE_VOXELS = (0.0, 0.5, 1.0)


def sphere_mesh(radius: float, n: int = 192):
    x = np.linspace(-1.2, 1.2, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    return marching_cubes(np.sqrt(X**2 + Y**2 + Z**2) - radius, np.full(3, -1.2), x[1] - x[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/tsdf_truncation.json"))
    args = ap.parse_args()
    ring = ring_cameras(8, size=96)
    cams = ring + sphere_cameras_around(16, ring[0])
    grid = VoxelGrid.around(np.full(3, -1.0), np.full(3, 1.0), 64)
    shapes = {
        "sphere": (lambda c: sphere_depth(c, 0.8), sphere_mesh(0.8)),
        "cube": (lambda c: cube_depth(c, 0.6), box_mesh(0.6)),
    }
    rows = []
    for shape, (depth_fn, truth) in shapes.items():
        exact = [(c, *depth_fn(c)) for c in cams]
        for noise in NOISE_VOXELS:
            rng = numpy_rng(0, "tsdf_truncation", shape, str(noise))
            views = [View(c, d + noise * grid.voxel * rng.standard_normal(d.shape), a) for c, d, a in exact]
            for trunc in TRUNCATIONS:
                tsdf = fuse_narrow_band(grid, views, FusionRule(trunc * grid.voxel, 0.5, 0.5, 0.0))
                mesh = largest_component(marching_cubes(tsdf.field, grid.origin, grid.voxel))
                m = geometry_metrics(mesh, truth, count=100_000, seed=0)
                row = {"shape": shape, "noise_voxels": noise, "truncation_voxels": trunc}
                row.update({k: m[k] for k in ("chamfer_l1", "fscore_1pct", "normal_consistency")})
                rows.append(row)
                print(json.dumps(row), flush=True)
    args.out.write_text(json.dumps({"voxel": grid.voxel, "rows": rows}, indent=2))


if __name__ == "__main__":
    main()
