"""Where a final mesh's geometric error lies (issue 35): by which way the surface faces, and whether the
surface far from the truth lies above or below it.

Per dev scene: the final model of a ``repair_dev.py`` variant (its ``repair_dir`` in ``--models``), meshed
with the mesh step's defaults, is sampled uniformly (``--samples`` per surface, seed 0) beside the
ground-truth mesh. "Up" is the training cameras' mean up vector; a sample faces up / down / sideways when
its face normal's component along up is > 0.5 / < -0.5 / between. Reported: the training cameras'
elevations above the plane through the hull box's centre, accuracy (predicted -> truth) and completeness
(truth -> predicted) per facing, the share of predicted samples farther than ``--far`` x the truth's
bounding radius from it, how many of those lie above their nearest true point (along up) and their
heights above it.

    python benchmarks/archive/geometry_error_where.py --data ../shared/data/dev \\
        --models benchmarks/results/repair_dev_prior2_ablations.json --variant realesr \\
        --out benchmarks/results/geometry_error_where.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from _final_models import final_gaussians, load_final  # benchmarks/ is on sys.path as a script
from scipy.spatial import cKDTree

from go_core.mesh.extract import mesh_from_gaussians
from go_core.mesh.settings import MeshSettings
from go_core.metrics.geometry import bounding_radius, sample_surface
from go_core.seeding import numpy_rng

SCENES = ("alphabet_soup", "basket", "milk", "plate", "white_bowl")


def camera_frame(cams, box) -> tuple[np.ndarray, list[float]]:
    """(unit up vector, elevation of each camera in degrees above the plane through the box's centre)."""
    c2w = [np.linalg.inv(np.asarray(c.world_to_cam, np.float64)) for c in cams]
    up = -np.mean([m[:3, 1] for m in c2w], axis=0)  # OpenCV: +y points down in the image
    up /= np.linalg.norm(up)
    centre = 0.5 * (np.asarray(box[0], np.float64) + np.asarray(box[1], np.float64))
    elev = []
    for m in c2w:
        d = m[:3, 3] - centre
        elev.append(round(float(np.degrees(np.arcsin(d @ up / np.linalg.norm(d)))), 1))
    return up, elev


def by_facing(normals: np.ndarray, dist: np.ndarray, up: np.ndarray) -> dict:
    """Share of the samples and their mean distance, for surface facing up, down and sideways."""
    along = normals @ up
    out = {}
    for name, sel in (("up", along > 0.5), ("down", along < -0.5), ("side", np.abs(along) <= 0.5)):
        out[name] = {"share": round(float(sel.mean()), 3),
                     "mean_distance": round(float(dist[sel].mean()), 4) if sel.any() else None}  # fmt: skip
    return out


def quantiles(values: np.ndarray) -> list[float] | None:
    """The 10th, 50th and 90th percentiles (None for no values)."""
    if not len(values):
        return None
    return [round(float(q), 3) for q in np.quantile(values, [0.1, 0.5, 0.9])]


def measure(scene_dir: Path, gaussians: Path, samples: int, far: float) -> dict:
    final = load_final(scene_dir, gaussians)
    cams, box, gt = final.cameras, final.box, final.truth
    up, elevations = camera_frame(cams, box)
    mesh, _ = mesh_from_gaussians(final.gaussians, cams, box, MeshSettings(), final.masks)
    radius = bounding_radius(gt)
    pp, pn = sample_surface(mesh, samples, numpy_rng(0, "geometry", "pred"))
    gp, gn = sample_surface(gt, samples, numpy_rng(0, "geometry", "gt"))
    completeness = cKDTree(pp).query(gp)[0]
    accuracy, nearest = cKDTree(gp).query(pp)
    far_sel = accuracy > far * radius
    height = (pp[far_sel] - gp[nearest[far_sel]]) @ up / radius
    return {
        "gaussians": str(gaussians),
        "camera_elevations_deg": elevations,
        "accuracy": round(float(accuracy.mean()), 4),
        "completeness": round(float(completeness.mean()), 4),
        "accuracy_by_facing": by_facing(pn, accuracy, up),
        "completeness_by_facing": by_facing(gn, completeness, up),
        "far_share": round(float(far_sel.mean()), 3),
        "far_above_share": round(float((height > 0).mean()), 3) if far_sel.any() else None,
        "far_height_over_radius_quantiles_10_50_90": quantiles(height),
        "truth_height_range": [round(float(x), 3) for x in ((gp @ up).min(), (gp @ up).max())],
        "mesh_height_range": [round(float(x), 3) for x in ((pp @ up).min(), (pp @ up).max())],
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--models", type=Path, required=True, help="a repair_dev.py JSON (repair_dir per scene)")
    ap.add_argument("--variant", default="realesr")
    ap.add_argument("--scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--far", type=float, default=0.04, help="far: farther than this x the truth's radius")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    models = final_gaussians(args.models, args.variant)
    result = {"command": "python benchmarks/archive/geometry_error_where.py " + " ".join(argv or []),
              "settings": {"samples": args.samples, "far": args.far, "variant": args.variant,
                           "models": str(args.models)}, "scenes": {}}  # fmt: skip
    for name in args.scenes:
        result["scenes"][name] = measure(args.data / name, models[name], args.samples, args.far)
        print(name, json.dumps(result["scenes"][name]), flush=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
