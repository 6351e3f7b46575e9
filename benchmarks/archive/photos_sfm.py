"""SfM settings on a photo set with a reference/ folder (issue 32): the product's own SfM (``run_sfm``, one
thread, as the scene step runs it) on the product's own auto masks, for several feature sizes, feature
counts and pair windows; scored against ``reference/`` (evaluation only): photos posed, rotation error
after a similarity alignment of the camera centres, focal length, seconds.

The masks are the scene step's (u2netp on the photos at ``MASK_SIZE``, before the pose vote),
made once and kept in ``--tmp``, resized to the feature size; ``--masks reference`` uses the reference
masks instead (to separate mask error from SfM error). The product ran SfM at 512 px (sfm_size 640 was
capped by the photo size) until the scene step read the photos at the larger of the two.

    python benchmarks/archive/photos_sfm.py --variant 640:2048:6 --variant 800:4096:6
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/ (photos.py), from archive/
from photos import DATA, _reference, rotation_errors  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "results" / "photos_sfm_ethiopian_head.json"


def _auto_masks(files, tmp: Path) -> list[np.ndarray]:
    """The scene step's auto masks (``photo_masks``: u2netp on the photos read at ``MASK_SIZE``, whatever
    ``scene.photo_size`` is), cached in ``tmp``."""
    import fcntl

    from go_core.photos.masks import photo_masker
    from go_core.photos.scene import MASK_SIZE, photo_masks

    cache = tmp / f"auto_masks_{MASK_SIZE}.npz"
    tmp.mkdir(parents=True, exist_ok=True)
    with open(tmp / "masks.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not cache.is_file():
            masker, _ = photo_masker("auto")
            ms, source = photo_masks(files, masker)
            if source != "auto":
                raise SystemExit(f"{files[0].path.parent}: the photos carry alpha masks, not auto masks")
            np.savez_compressed(cache, masks=np.stack(ms))
        return list(np.load(cache)["masks"])


def photo_files_of(data: Path) -> list:
    """The header facts of every photo of the set's ``images/`` (go_core.photos.folder)."""
    from go_core.photos.folder import photo_files, scan_photo
    from go_core.scene.common import Problems

    return [scan_photo(f, Problems(strict=True)) for f in photo_files(data / "images")]


def sfm_photos(files: list, masks: list[np.ndarray], size: int) -> list:
    """SfmPhotos of ``files`` read at ``size`` (long side), with ``masks`` resized to them, their camera
    groups and EXIF focal lengths in pixels of the image as read: what the scene step gives SfM."""
    import cv2

    from go_core.photos.folder import camera_groups, read_photo
    from go_core.photos.sfm import SfmPhoto

    images = [read_photo(f, size)[0] for f in files]
    masks = [
        cv2.resize(m, im.shape[1::-1], interpolation=cv2.INTER_LINEAR)
        for m, im in zip(masks, images, strict=True)
    ]
    groups = camera_groups(files)
    return [
        SfmPhoto(f.name, im, m, g, f.focal_px(max(im.shape[:2])))
        for f, im, m, g in zip(files, images, masks, groups, strict=True)
    ]


def _photos(data: Path, size: int, masks: str, tmp: Path):
    """SfmPhotos at ``size`` with the product's auto masks (cached) or the reference masks."""
    from go_core.io.images import read_mask

    files = photo_files_of(data)
    if masks == "reference":
        ms = [read_mask(data / "reference" / "masks" / f"{f.name}.png") for f in files]
    else:
        ms = _auto_masks(files, tmp)
    return sfm_photos(files, ms, size)


def run_variant(data: Path, variant: str, masks: str, tmp: Path, matcher: str, agreement: bool) -> dict:
    from go_core.photos.agreement import sfm_agreeing
    from go_core.photos.sfm import SfmSettings, run_sfm

    size, features, window = (int(x) for x in variant.split(":"))
    photos = _photos(data, size, masks, tmp)
    start = time.perf_counter()
    sfm = partial(
        run_sfm,
        settings=SfmSettings(matcher, features, window),
        use_masks=True,
        log_path=tmp / f"colmap_{variant.replace(':', '_')}.log",
    )
    out, left_out = sfm_agreeing(photos, sfm) if agreement else (sfm(photos), {})
    seconds = time.perf_counter() - start
    ref = _reference(data)
    rot = rotation_errors(out.cameras, ref)
    focal = [
        c.K[0, 0] * max(ref[n].width, ref[n].height) / max(c.width, c.height) for n, c in out.cameras.items()
    ]
    return {
        "size": size,
        "features": features,
        "window": window,
        "matcher": matcher,
        "masks": masks,
        "registered": len(out.cameras),
        "photos": len(photos),
        "missing": out.missing,
        "agreement_check": agreement,
        "left_out_disagreeing_with_masks": left_out,
        "rotation_error_deg": {"median": float(np.median(list(rot.values()))), "max": max(rot.values())},
        "worst": sorted(rot, key=rot.get)[-3:],
        "mean_reprojection_px": round(out.mean_reprojection_px, 4),
        "focal_px_at_reference_size": round(float(np.median(focal)), 1),
        "reference_focal_px": round(float(next(iter(ref.values())).K[0, 0]), 1),
        "pairs": out.num_pairs,
        "sfm_s": round(seconds, 1),
        "threads": 1,
    }


def _save(out: Path, key: str, result: dict, data: Path) -> None:
    """Add one variant to the JSON (locked: variants run side by side in two CPU slots)."""
    import fcntl

    with open(out.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        doc = json.loads(out.read_text()) if out.is_file() else {"data": str(data), "runs": {}}
        doc["runs"][key] = result
        out.write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")


def table(doc: dict) -> str:
    """The markdown table of docs/photos.md from the JSON."""
    rows = [
        "| SfM size | features | agreement check | posed | rotation error median / max (deg) "
        "| focal (px, ref 1885.9) | left out by the check | SfM s (1 thread) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    runs = sorted(doc["runs"].values(), key=lambda r: (r["size"], r["features"], r["agreement_check"]))
    for r in runs:
        rot = r["rotation_error_deg"]
        left_out = ", ".join(r.get("left_out_disagreeing_with_masks") or []) or "-"
        rows.append(
            f"| {r['size']} | {r['features']} | {'yes' if r['agreement_check'] else 'no'} "
            f"| {r['registered']}/{r['photos']} | {rot['median']:.2f} / {rot['max']:.2f} "
            f"| {r['focal_px_at_reference_size']} | {left_out} "
            f"| {r['sfm_s']} |"
        )
    return "\n".join(rows)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--variant", action="append", default=[], help="SIZE:FEATURES:WINDOW")
    p.add_argument("--table", action="store_true", help="print the docs table of the JSON")
    p.add_argument("--masks", choices=["auto", "reference"], default="auto")
    p.add_argument("--matcher", choices=["sift", "disk"], default="sift")
    p.add_argument("--no-agreement", action="store_true", help="SfM alone, without the pose-mask agreement")
    p.add_argument("--data", type=Path, default=DATA)
    p.add_argument("--tmp", type=Path, default=Path("/tmp/go-photos-sfm"))
    p.add_argument("--out", type=Path, default=OUT)
    args = p.parse_args()
    if args.table:
        print(table(json.loads(args.out.read_text())))
        return 0
    for variant in args.variant:
        result = run_variant(args.data, variant, args.masks, args.tmp, args.matcher, not args.no_agreement)
        key = f"{args.matcher}:{args.masks}:{variant}" + (":no_agreement_check" if args.no_agreement else "")
        _save(args.out, key, result, args.data)
        print(json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
