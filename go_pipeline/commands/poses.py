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
        help="no poses given: run pycolmap SfM on the images, verify the result and write NeRF-style "
        "transforms here (nothing is written when a check fails; --json writes the checks)",
    )
    p.add_argument(
        "--allow-unregistered",
        action="store_true",
        help="with --estimate: write the poses of the registered images even when some could not be",
    )
    p.add_argument("--strict", action="store_true", help="exit 1 when any view could not be verified")
    p.add_argument(
        "--matcher",
        choices=["sift", "disk"],
        default="sift",
        help="features and matcher: sift (COLMAP's; default) or disk (DISK + LightGlue, learned; weights "
        "from `go-pipeline weights fetch`)",
    )
    p.set_defaults(func=main)


def _image_views(folder: Path) -> list:
    from go_core.io.images import IMAGE_EXTENSIONS, read_image, split_rgb_alpha

    if not folder.is_dir():
        raise GoError("not a folder of images", folder)
    files = sorted(f for f in folder.iterdir() if f.suffix in IMAGE_EXTENSIONS)
    if len(files) < 3:
        raise GoError(f"found {len(files)} images; SfM needs at least 3", folder)
    views = []
    for f in files:
        rgb, alpha = split_rgb_alpha(read_image(f))
        views.append(SimpleNamespace(name=f.name, image=rgb, mask=alpha, source=f))
    return views


def _transforms(views: list, cams: dict, out: Path) -> dict:
    """NeRF-style transforms; each ``file_path`` is relative to the JSON's folder, without the extension."""
    import os

    first = next(iter(cams.values()))
    base = out.resolve().parent
    frames = [
        {
            "file_path": Path(os.path.relpath(v.source.resolve().with_suffix(""), base)).as_posix(),
            "transform_matrix": cams[v.name].opengl_c2w.tolist(),
        }
        for v in views
        if v.name in cams
    ]
    return {
        "camera_angle_x": 2 * math.atan(first.width / (2 * first.K[0, 0])),
        "fl_x": float(first.K[0, 0]),
        "fl_y": float(first.K[1, 1]),
        "cx": float(first.K[0, 2]),
        "cy": float(first.K[1, 2]),
        "w": first.width,
        "h": first.height,
        "frames": frames,
        "note": "pycolmap incremental SfM: arbitrary world frame and scale",
    }


def estimate(
    folder: Path, out: Path, threads: int, allow_unregistered: bool, report: Path | None, matcher: str
) -> int:
    """SfM, then ``verify_poses`` on the result: the transforms are written only when every check passes."""
    from go_core.errors import PoseCheckError
    from go_core.io.atomic import atomic_write_json
    from go_core.poses.estimate import estimate_poses

    views = _image_views(folder)
    try:
        est = estimate_poses(
            views, matcher=matcher, num_threads=threads, allow_unregistered=allow_unregistered
        )
        if est.missing and not allow_unregistered:
            est.verdict.problems[0] += "; --allow-unregistered writes the rest"
    except PoseCheckError as exc:
        raise GoError(f"could not estimate poses: {exc}", folder) from exc
    sfm, verdict, missing = est.sfm, est.verdict, est.missing
    registered = [v for v in views if v.name in sfm.cameras]
    print(f"registered {len(registered)} of {len(views)} images ({matcher}); {sfm.num_points} points")
    cov = verdict.mask_coverage
    print(
        f"checks: rotation spread {verdict.rotation_spread_deg:.1f}°, mean reprojection error "
        f"{sfm.mean_reprojection_px:.2f} px, fewest points per image {verdict.min_observations}, "
        + ("masks not checked (none)" if cov is None else f"lowest mask coverage {min(cov.values()):.3f}")
    )
    if report is not None:
        from go_core.io.atomic import atomic_write_text

        d = {"registered": [v.name for v in registered], "not_registered": missing, **verdict.to_dict()}
        atomic_write_text(report, json.dumps(d, indent=2, sort_keys=True) + "\n")
    if verdict.problems:
        print(f"POSES NOT WRITTEN: the estimate failed {len(verdict.problems)} check(s):")
        for p in verdict.problems:
            print(f"  - {p}")
        return 1
    for note in verdict.notes:
        print(f"note: {note}")
    atomic_write_json(out, _transforms(views, sfm.cameras, out))
    print(f"poses -> {out}")
    return 0


def _print_report(report) -> None:
    head = f"{'view':<28}{'pairs ok/verified':>18}{'obs':>6}{'median px':>11}{'p90 px':>9}{'mask cov':>10}"
    print(head + "  status")
    for r in report.images:
        med = "-" if r.median_px is None else f"{r.median_px:.2f}"
        p90 = "-" if r.p90_px is None else f"{r.p90_px:.2f}"
        cov = "-" if r.mask_coverage is None else f"{r.mask_coverage:.3f}"
        pairs = f"{r.consistent_pairs}/{r.verified_pairs}"
        print(f"{r.name:<28}{pairs:>18}{r.observations:>6}{med:>11}{p90:>9}{cov:>10}  {r.status} {r.reason}")
    print(
        f"{report.num_verified_pairs} verified pairs, {report.num_tracks} tracks, "
        f"{report.wide_pairs_ignored} disagreeing wide-baseline pairs ignored, "
        f"{report.refuted_pairs_ignored} refuted by the silhouettes; "
        f"{len(report.flagged)} flagged, {len(report.unverified)} unverified"
    )
    for note in report.notes:
        print(f"note: {note}")


def main(args: argparse.Namespace) -> int:
    if args.estimate is not None:
        matcher = args.matcher
        return estimate(args.scene, args.estimate, args.threads, args.allow_unregistered, args.json, matcher)
    from go_core.poses.check import check_poses
    from go_core.scene.loader import load_scene

    scene = load_scene(args.scene)
    views = {"train": scene.train, "test": scene.test, "all": scene.train + scene.test}[args.split]
    if len(views) < 2:
        raise GoError(f"the {args.split} split has {len(views)} view(s); the check needs 2", args.scene)
    matcher = args.matcher
    report = check_poses(views, threshold_px=args.threshold, num_threads=args.threads, matcher=matcher)
    print(f"matcher: {matcher}")
    _print_report(report)
    if args.json is not None:
        from go_core.io.atomic import atomic_write_text

        atomic_write_text(args.json, json.dumps(report.to_dict(), indent=2, sort_keys=True) + "\n")
    if report.masks_consistent is None:
        print("masks: not checked")
    elif report.masks_consistent:
        cov = min(r.mask_coverage for r in report.images)
        print(f"masks: consistent with the poses (lowest coverage {cov:.3f})")
    else:
        print(f"MASKS DISAGREE: {report.mask_problem}")
    if report.flagged:
        print("POSES FLAGGED: " + ", ".join(report.flagged))
    if not report.ok:
        return 1
    checked = len(views) - len(report.unverified)
    if checked == 0:
        why = "no view could be checked with features"
        if args.split != "all" and scene.train and scene.test:
            why += " (--split all adds the scene's other views as evidence)"
        masks = "; the masks agree with the poses" if report.masks_consistent else ""
        print(f"poses NOT verified by features: {why}{masks}")
    else:
        extra = f" ({len(report.unverified)} view(s) could not be verified)" if report.unverified else ""
        print(f"poses OK: {checked} of {len(views)} views verified by features{extra}")
    return 1 if args.strict and report.unverified else 0
