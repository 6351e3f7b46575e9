"""How many DISK + LightGlue matches between a dev scene's 4 training views are right, by confidence floor.

Issue 19's question: can feature matches between the training views (90° apart) correct approximate poses
beyond what the silhouettes do? For every pair of a scene's training views: DISK keypoints inside the
dilated masks (as the pose check extracts them), LightGlue's mutual matches with their confidences, and
for each confidence floor the matches kept and how many are right: triangulated with the TRUE cameras, the
point reprojects within ``--px`` pixels in both views and lies within ``--surface`` × the mesh's diagonal of
the scene mesh's surface (``mesh_world.npz``, densely sampled). The pose estimate keeps matches above 0.9
(``ESTIMATE_MIN_CONFIDENCE``), where on real/ethiopian_head's 30°-apart photos every verified pair was right.

    python benchmarks/archive/training_view_matches.py --data ../shared/data/dev \
        --out benchmarks/results/training_view_matches.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

DEV = Path(__file__).resolve().parents[3] / "shared" / "data" / "dev"
FLOORS = (0.1, 0.5, 0.8, 0.9, 0.95)


def surface_samples(vertices: np.ndarray, faces: np.ndarray, count: int, seed: int = 0) -> np.ndarray:
    """``count`` points spread uniformly (by area) over a triangle mesh."""
    rng = np.random.default_rng(seed)
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    pick = rng.choice(len(faces), count, p=area / area.sum())
    uv = rng.random((count, 2))
    flip = uv.sum(1) > 1
    uv[flip] = 1 - uv[flip]
    t = tri[pick]
    return t[:, 0] + uv[:, :1] * (t[:, 1] - t[:, 0]) + uv[:, 1:] * (t[:, 2] - t[:, 0])


def right_matches(cams, xy0, xy1, tree, diag: float, px: float, surface: float) -> np.ndarray:
    """Per match: triangulated with the true cameras, it reprojects within ``px`` in both views and lies
    within ``surface`` × ``diag`` of the mesh surface (``tree``: a KD-tree of surface samples)."""
    from go_core.poses.tracks import triangulate_dlt

    P = np.stack([c.K @ c.world_to_cam[:3] for c in cams])
    X = np.stack([triangulate_dlt(P, np.stack([a, b])) for a, b in zip(xy0, xy1, strict=True)])
    finite = np.all(np.isfinite(X), axis=1)
    X = np.where(finite[:, None], X, 0.0)
    err0 = np.linalg.norm(cams[0].project(X)[0] - xy0, axis=1)
    err = np.maximum(err0, np.linalg.norm(cams[1].project(X)[0] - xy1, axis=1))
    return finite & (err < px) & (tree.query(X)[0] < surface * diag)


def scene_pairs(scene_dir: Path, max_keypoints: int, dilate_px: int, px: float, surface: float) -> dict:
    import torch
    from scipy.spatial import cKDTree

    from go_core.features.weights import load_disk, load_lightglue
    from go_core.poses.matching import disk_features
    from go_core.scene.loader import load_scene

    scene = load_scene(scene_dir)
    mesh = np.load(scene_dir / "mesh_world.npz")
    vertices = np.asarray(mesh["vertices"], np.float64)
    tree = cKDTree(surface_samples(vertices, np.asarray(mesh["faces"]), 400_000))
    diag = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    disk, glue = load_disk(), load_lightglue()
    with torch.no_grad():
        feats = disk_features(disk, scene.train, max_keypoints, dilate_px)  # as the pose check extracts them
        out = {}
        cams = scene.train_cameras
        for i in range(len(feats)):
            for j in range(i + 1, len(feats)):
                (fi, si), (fj, sj) = feats[i], feats[j]
                m, conf = glue(fi.xy, fi.descriptors, si, fj.xy, fj.descriptors, sj)
                m, conf = m.numpy(), conf.numpy()
                xy0 = fi.xy_subpixel.numpy()[m[:, 0]] + 0.5  # pixel centres at +0.5, as Camera.project
                xy1 = fj.xy_subpixel.numpy()[m[:, 1]] + 0.5
                right = right_matches([cams[i], cams[j]], xy0, xy1, tree, diag, px, surface)
                angle = np.degrees(np.arccos(np.clip(np.dot(cams[i].forward, cams[j].forward), -1, 1)))
                out[f"{scene.train[i].name}-{scene.train[j].name}"] = {
                    "angle_deg": round(float(angle), 1),
                    "kept_right_by_floor": {
                        str(t): [int((conf > t).sum()), int((right & (conf > t)).sum())] for t in FLOORS
                    },
                }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEV)
    ap.add_argument("--scenes", nargs="+", default=["milk", "alphabet_soup", "basket", "plate", "white_bowl"])
    ap.add_argument("--max-keypoints", type=int, default=2048)
    ap.add_argument("--dilate-px", type=int, default=4, help="mask dilation for the keypoints (the check's)")
    ap.add_argument("--px", type=float, default=3.0, help="reprojection tolerance of a right match")
    ap.add_argument("--surface", type=float, default=0.02, help="surface tolerance, x the mesh diagonal")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    import torch

    torch.set_num_threads(1)
    result: dict = {
        "command": "python benchmarks/archive/training_view_matches.py " + " ".join(os.sys.argv[1:]),
        "machine": platform.processor() or platform.machine(),
        "floors": list(FLOORS),
        "cells": "per pair of training views and confidence floor: [matches kept, of them right]",
        "scenes": {},
    }
    for name in args.scenes:
        t0 = time.process_time()
        pairs = scene_pairs(args.data / name, args.max_keypoints, args.dilate_px, args.px, args.surface)
        totals = {
            str(t): [sum(p["kept_right_by_floor"][str(t)][k] for p in pairs.values()) for k in (0, 1)]
            for t in FLOORS
        }
        cpu_s = round(time.process_time() - t0, 1)
        result["scenes"][name] = {"pairs": pairs, "totals": totals, "cpu_s": cpu_s}
        print(name, totals, flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
