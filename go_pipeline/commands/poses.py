"""`go-pipeline poses SCENE`: check the scene's given poses against its images with COLMAP (pycolmap), or
estimate poses with incremental SfM (`--estimate OUT.json`) for a folder of images without poses."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from types import SimpleNamespace

from go_core.errors import GoError


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("poses", help="check the given camera poses with COLMAP features (pycolmap)")
    p.add_argument("scene", type=Path, help="scene folder (or, with --estimate, a folder of images)")
    p.add_argument(
        "--split",
        choices=["all", "train", "test"],
        default="all",
        help="views to check (default all: more views give more evidence)",
    )
    p.add_argument(
        "--threshold",
        type=float,
        default=1.5,
        help="max median error in px for a 256-px image (scales with image size; default 1.5)",
    )
    p.add_argument("--json", type=Path, default=None, help="also write the full report as JSON here")
    p.add_argument("--threads", type=int, default=2, help="pycolmap threads (default 2)")
    p.add_argument(
        "--estimate",
        type=Path,
        default=None,
        metavar="OUT.json",
        help="no poses given: run pycolmap SfM on the images and write NeRF-style transforms here",
    )
    p.set_defaults(func=main)


def _image_views(folder: Path) -> list:
    from go_core.io.images import IMAGE_EXTENSIONS, read_image, split_rgb_alpha

    files = sorted(f for f in folder.iterdir() if f.suffix in IMAGE_EXTENSIONS)
    if len(files) < 3:
        raise GoError(f"found {len(files)} images; SfM needs at least 3", folder)
    views = []
    for f in files:
        rgb, alpha = split_rgb_alpha(read_image(f))
        views.append(SimpleNamespace(name=f.name, image=rgb, mask=alpha, source=f))
    return views


def estimate(folder: Path, out: Path, threads: int) -> int:
    from go_core.io.atomic import atomic_write_json
    from go_core.posecheck import estimate_poses

    views = _image_views(folder)
    cams = estimate_poses(views, num_threads=threads)
    first = next(iter(cams.values()))
    frames = [
        {"file_path": Path(v.name).stem, "transform_matrix": cams[v.name].opengl_c2w.tolist()}
        for v in views
        if v.name in cams
    ]
    atomic_write_json(
        out,
        {
            "camera_angle_x": 2 * math.atan(first.width / (2 * first.K[0, 0])),
            "fl_x": float(first.K[0, 0]),
            "fl_y": float(first.K[1, 1]),
            "cx": float(first.K[0, 2]),
            "cy": float(first.K[1, 2]),
            "w": first.width,
            "h": first.height,
            "frames": frames,
            "note": "pycolmap incremental SfM: arbitrary world frame and scale",
        },
    )
    missing = [v.name for v in views if v.name not in cams]
    print(f"registered {len(cams)} of {len(views)} images -> {out}")
    if missing:
        print("not registered: " + ", ".join(missing))
    return 0


def main(args: argparse.Namespace) -> int:
    if args.estimate is not None:
        return estimate(args.scene, args.estimate, args.threads)
    from go_core.posecheck import check_poses
    from go_core.scene import load_scene

    scene = load_scene(args.scene)
    views = {"train": scene.train, "test": scene.test, "all": scene.train + scene.test}[args.split]
    report = check_poses(views, threshold_px=args.threshold, num_threads=args.threads)
    print(f"{'view':<28}{'pairs ok/verified':>18}{'obs':>6}{'median px':>11}{'p90 px':>9}  status")
    for r in report.images:
        med = "-" if r.median_px is None else f"{r.median_px:.2f}"
        p90 = "-" if r.p90_px is None else f"{r.p90_px:.2f}"
        pairs = f"{r.consistent_pairs}/{r.verified_pairs}"
        print(f"{r.name:<28}{pairs:>18}{r.observations:>6}{med:>11}{p90:>9}  {r.status} {r.reason}")
    print(
        f"{report.num_verified_pairs} verified pairs, {report.num_tracks} tracks; "
        f"{len(report.flagged)} flagged, {len(report.unverified)} unverified"
    )
    if args.json is not None:
        from go_core.io.atomic import atomic_write_text

        atomic_write_text(args.json, json.dumps(report.to_dict(), indent=2, sort_keys=True) + "\n")
    if report.flagged:
        print("POSES FLAGGED: " + ", ".join(report.flagged))
        return 1
    print("poses OK" + (" (some views could not be verified)" if report.unverified else ""))
    return 0
