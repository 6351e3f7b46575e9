"""Is the photo route's SfM repeatable? (issue 33's note: one run posed 5 photos wrongly, its rerun did not.)

``--part runs``: the scene step's masks (u2netp) and masked SIFT SfM on a photo set, ``--repeats`` times at
``--threads`` (the step's thread count), each in a fresh process, at the ``scene`` step's default params.
Each run keeps a digest of every mask, every photo's keypoints and descriptors, every pair's matches and
two-view geometry, and the poses; the JSON says which of them differ from the first run's.

``--part mapper``: COLMAP's mapper alone on the first run's database, at each ``--seeds`` seed, with its
structure-less registration fallback on and off: the photos registered and the largest pose difference.

    python benchmarks/archive/sfm_repeat.py --part runs --repeats 4
    python benchmarks/archive/sfm_repeat.py --part mapper --seeds 0 1 2 3
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "photos" / "ethiopian_head"
OUT = Path(__file__).resolve().parents[1] / "results" / "photos_sfm_repeatability.json"

sys.path.insert(0, str(Path(__file__).resolve().parent))
from photos_sfm import photo_files_of, sfm_photos  # noqa: E402


def _digest(a) -> str:
    return hashlib.sha1(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def database_digest(path: Path) -> dict:
    """Digests of the keypoints and descriptors of every photo, the matches and two-view geometry of
    every pair, in a COLMAP database."""
    import pycolmap

    db = pycolmap.Database.open(str(path))
    try:
        names = {im.image_id: im.name for im in db.read_all_images()}
        out = {"keypoints": {}, "descriptors": {}, "matches": {}, "geometries": {}}
        for i, n in names.items():
            out["keypoints"][n] = _digest(db.read_keypoints(i))
            out["descriptors"][n] = _digest(db.read_descriptors(i).data)
        for i in names:
            for j in names:
                key = f"{names[i]}-{names[j]}"
                if i < j and db.exists_matches(i, j):
                    out["matches"][key] = _digest(db.read_matches(i, j))
                if i < j and db.exists_two_view_geometry(i, j):
                    g = db.read_two_view_geometry(i, j)
                    out["geometries"][key] = f"{int(g.config)}:{_digest(g.inlier_matches)}"
        return out
    finally:
        db.close()


def one_run(data: Path, keep: Path, threads: int) -> dict:
    """The scene step's masks and masked SfM (go_core.photos.scene, steps/scene.py) at its default params,
    COLMAP's work dir kept in ``keep``."""
    import torch
    from go_pipeline.steps.params import SceneParams

    from go_core.photos import sfm as sfm_mod
    from go_core.photos.masks import photo_masker
    from go_core.photos.scene import photo_masks

    torch.set_num_threads(threads)
    p = SceneParams()

    @contextlib.contextmanager
    def kept_dir(prefix: str = "", dir=None):
        shutil.rmtree(keep, ignore_errors=True)
        keep.mkdir(parents=True)
        yield str(keep)

    sfm_mod.tempfile.TemporaryDirectory = kept_dir  # this process only: keep the database
    files = photo_files_of(data)
    masks, _ = photo_masks(files, photo_masker(p.photo_masks, threads=threads)[0])
    settings = sfm_mod.SfmSettings(
        p.pose_matcher, p.sfm_features, p.sfm_window, extraction_workers=threads, matching_threads=threads
    )
    photos = sfm_photos(files, masks, p.sfm_size)  # at sfm_size, as the step reads them when larger
    out = sfm_mod.run_sfm(photos, settings, use_masks=True)
    return {
        "threads": threads,
        "registered": len(out.cameras),
        "missing": out.missing,
        "mean_reprojection_px": out.mean_reprojection_px,
        "masks": {f.name: _digest(m) for f, m in zip(files, masks, strict=True)},
        "database": database_digest(keep / "database.db"),
        "poses": {n: c.world_to_cam.tolist() for n, c in out.cameras.items()},
    }


def compare(first: dict, run: dict) -> dict:
    """What differs from the first run: counts per kind, and the largest pose difference."""
    diff = {"masks": sum(first["masks"][k] != v for k, v in run["masks"].items())}
    for kind, digests in run["database"].items():
        ref = first["database"][kind]
        diff[kind] = sum(ref.get(k) != v for k, v in digests.items()) + len(set(ref) - set(digests))
    common = set(first["poses"]) & set(run["poses"])
    diff["registered"] = run["registered"]
    diff["max_pose_difference"] = max(
        float(np.abs(np.asarray(first["poses"][k]) - np.asarray(run["poses"][k])).max()) for k in common
    )
    return diff


def runs(args) -> dict:
    records = []
    for k in range(args.repeats):
        keep = args.tmp / f"run_{k}"
        cmd = [sys.executable, __file__, "--part", "one", "--data", str(args.data), "--tmp", str(keep)]
        subprocess.run(cmd + ["--threads", str(args.threads)], check=True)
        records.append(json.loads((keep / "run.json").read_text()))
        print(f"run {k}: {records[-1]['registered']} registered", flush=True)
    first = records[0]
    return {
        "command": "python benchmarks/archive/sfm_repeat.py --part runs "
        f"--repeats {args.repeats} --threads {args.threads}",
        "first": {k: first[k] for k in ("registered", "missing", "mean_reprojection_px")},
        "differences_from_the_first": [compare(first, r) for r in records[1:]],
    }


def mapper(args) -> dict:
    """COLMAP's mapper on the first run's database at each seed, with the scene step's mapper options
    (``mapper_options``), the fallback on and off."""
    from dataclasses import replace

    import pycolmap
    from go_pipeline.steps.params import SceneParams

    from go_core.photos.sfm import SfmSettings, mapper_options

    p = SceneParams()
    settings = SfmSettings(p.pose_matcher, p.sfm_features, p.sfm_window)
    src = args.tmp / "run_0" / "sfm"
    poses, rows = {}, []
    for fallback in (True, False):
        for seed in args.seeds:
            with tempfile.TemporaryDirectory() as t:
                work = Path(t)
                shutil.copy(src / "database.db", work / "database.db")
                (work / "sparse").mkdir()
                o = mapper_options(replace(settings, seed=seed, structure_less_fallback=fallback))
                recs = pycolmap.incremental_mapping(
                    work / "database.db", src / "images", work / "sparse", options=o
                )
                best = max(recs.values(), key=lambda r: r.num_reg_images())
                poses[fallback, seed] = {
                    im.name: np.asarray(im.cam_from_world().matrix())
                    for im in best.images.values()
                    if im.has_pose
                }
                rows.append(
                    {
                        "fallback": fallback,
                        "seed": seed,
                        "models": sorted((r.num_reg_images() for r in recs.values()), reverse=True),
                    }
                )
    for row in rows:
        if not row["fallback"]:
            a, b = poses[True, row["seed"]], poses[False, row["seed"]]
            row["same_photos_as_fallback_on"] = sorted(a) == sorted(b)
            row["max_pose_difference_to_fallback_on"] = max(
                float(np.abs(a[k] - b[k]).max()) for k in a if k in b
            )
    return {
        "command": "python benchmarks/archive/sfm_repeat.py --part mapper --seeds "
        + " ".join(map(str, args.seeds)),
        "runs": rows,
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--part", choices=["runs", "mapper", "one"], required=True)
    p.add_argument("--data", type=Path, default=DATA)
    p.add_argument("--tmp", type=Path, default=Path("/tmp/go-sfm-repeat"))
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeats", type=int, default=4)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    p.add_argument("--out", type=Path, default=OUT)
    args = p.parse_args()
    if args.part == "one":
        (args.tmp / "run.json").write_text(json.dumps(one_run(args.data, args.tmp / "sfm", args.threads)))
        return 0
    doc = json.loads(args.out.read_text()) if args.out.is_file() else {"data": str(args.data)}
    doc[args.part] = runs(args) if args.part == "runs" else mapper(args)
    args.out.write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")
    print(json.dumps(doc[args.part], indent=1)[:3000])
    return 0


if __name__ == "__main__":
    sys.exit(main())
