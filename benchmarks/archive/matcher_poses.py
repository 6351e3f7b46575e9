"""SIFT vs DISK+LightGlue for the pose check and the pose estimate (issue 19's checks).

    python benchmarks/archive/matcher_poses.py --data ../shared/data \\
        --out benchmarks/results/matcher_poses.json
        [--estimate real/ethiopian_head real/blowtorch] [--check dev/plate dev/white_bowl]
        [--rotated dev/milk] [--degrees 5] [--matchers sift disk]

* estimate: pycolmap incremental SfM from the 4 training views alone and from all views (with masks);
  registered count, per-view rotation error against the given poses (after the best world rotation), and
  the verdict of ``verify_poses`` (what `poses --estimate` would do);
* check: all views with their given poses: flagged and unverified counts;
* rotated: the same check with test view 9 turned 5° (``--degrees``) about its x axis: must be caught
  (flagged, or the masks disagree).
Records wall and CPU seconds of each run (the machine is shared: compare CPU seconds).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from go_core.errors import PoseCheckError
from go_core.poses.check import check_poses
from go_core.poses.sfm import reconstruct
from go_core.poses.verify import verify_poses
from go_core.scene.loader import load_scene

MATCHERS = ("sift", "disk")


def rotation_errors(given: dict, estimated: dict) -> dict[str, float]:
    """Per view: the angle (degrees) between the estimated and given world-to-camera rotations once the
    estimate's world frame is rotated onto the given one (the rotation that best aligns all views)."""
    names = [n for n in estimated if n in given]
    rel = [given[n].world_to_cam[:3, :3].T @ estimated[n].world_to_cam[:3, :3] for n in names]
    u, _, vt = np.linalg.svd(np.sum(rel, axis=0))
    align = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt  # nearest rotation to the mean
    out = {}
    for n, r in zip(names, rel, strict=True):
        e = r @ align.T
        out[n] = float(np.degrees(np.arccos(np.clip((np.trace(e) - 1) / 2, -1, 1))))
    return out


def timed(fn):
    t, c = time.time(), time.process_time()
    res = fn()
    return res, round(time.time() - t, 1), round(time.process_time() - c, 1)


def estimate(views, matcher: str) -> dict:
    given = {v.name: v.camera for v in views}
    try:
        sfm, wall, cpu = timed(lambda: reconstruct(views, num_threads=2, matcher=matcher))
    except PoseCheckError as exc:
        return {"registered": 0, "of": len(views), "error": str(exc)}
    names = [v.name for v in views if v.name in sfm.cameras]
    verdict = verify_poses(
        [sfm.cameras[n] for n in names],
        [v.mask for v in views if v.name in sfm.cameras],
        mean_reprojection_px=sfm.mean_reprojection_px,
        observations=sfm.observations,
    )
    errs = rotation_errors(given, sfm.cameras) if len(names) >= 2 else {}
    return {
        "registered": len(names),
        "of": len(views),
        "rotation_error_deg": {k: round(v, 2) for k, v in errs.items()},
        "max_rotation_error_deg": round(max(errs.values()), 2) if errs else None,
        "within_5deg": sum(e < 5.0 for e in errs.values()),
        "verified_pairs": sfm.num_verified_pairs,
        "mean_reprojection_px": round(sfm.mean_reprojection_px, 3),
        "estimate_accepted": verdict.ok and len(names) == len(views),
        "problems": verdict.problems,
        "wall_s": wall,
        "cpu_s": cpu,
    }


def check(views, matcher: str) -> dict:
    rep, wall, cpu = timed(lambda: check_poses(views, num_threads=2, matcher=matcher))
    return {
        "views": len(views),
        "flagged": rep.flagged,
        "unverified": len(rep.unverified),
        "verified_pairs": rep.num_verified_pairs,
        "refuted_pairs": rep.refuted_pairs_ignored,
        "masks_consistent": rep.masks_consistent,
        "wall_s": wall,
        "cpu_s": cpu,
    }


def rotated(views, k: int, degrees: float = 5.0):
    out = list(views)
    out[k] = dataclasses.replace(views[k], camera=views[k].camera.turned(np.radians([degrees, 0.0, 0.0])))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--estimate", nargs="*", default=["real/ethiopian_head", "real/blowtorch"])
    ap.add_argument("--check", nargs="*", default=["dev/plate", "dev/white_bowl"])
    ap.add_argument("--rotated", nargs="*", default=["dev/milk"])
    ap.add_argument("--degrees", nargs="*", type=float, default=[5.0], help="turns of the rotated view")
    ap.add_argument("--matchers", nargs="*", default=list(MATCHERS))
    args = ap.parse_args()
    results = json.loads(args.out.read_text()) if args.out.exists() else {}

    def save() -> None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=2, sort_keys=True) + "\n")

    for name in args.estimate:
        scene = load_scene(args.data / name)
        for split, views in (("train", scene.train), ("all", scene.train + scene.test)):
            for m in args.matchers:
                results.setdefault("estimate", {}).setdefault(name, {}).setdefault(split, {})[m] = r = (
                    estimate(views, m)
                )
                print(name, split, m, {k: r.get(k) for k in ("registered", "of", "max_rotation_error_deg")})
                save()
    for name in args.check:
        scene = load_scene(args.data / name)
        for m in args.matchers:
            results.setdefault("check", {}).setdefault(name, {})[m] = r = check(scene.train + scene.test, m)
            print(name, "check", m, r)
            save()
    for name in args.rotated:
        scene = load_scene(args.data / name)
        for degrees in args.degrees:
            views = rotated(scene.train + scene.test, 9, degrees)
            for m in args.matchers:
                r = check(views, m)
                r["rotated_view"] = views[9].name
                r["caught"] = r["flagged"] == [views[9].name] or r["masks_consistent"] is False
                results.setdefault(f"rotated_{degrees:g}deg", {}).setdefault(name, {})[m] = r
                print(name, "rotated", degrees, m, r)
                save()


if __name__ == "__main__":
    main()
