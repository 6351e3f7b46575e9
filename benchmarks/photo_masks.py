"""Auto masks against a photo set's reference masks: per-photo IoU of each method (issue 32's mask checks).

    python benchmarks/photo_masks.py --data ../shared/data/photos/ethiopian_head \
        --out benchmarks/results/photo_masks.json [--methods grabcut u2netp_raw auto auto_box auto_box_poses]

Methods (the product's code; ``reference/`` is read for scoring and for the simulated user's box only):
* ``grabcut``: GrabCut seeded by the image border, as the product runs it on photos
  (``scene.photo_masks: grabcut``, and ``auto`` without the u2netp weights: ``grabcut_photo_mask``, at
  ``GRABCUT_SIZE`` px, the mask scaled back): the baseline;
* ``u2netp_raw``: u2netp on the whole photo at 320², threshold 0.5, nothing else;
* ``auto``: ``go_core.scene.auto_mask.auto_mask`` with the default settings, no hint;
* ``auto_vote``: the ``auto`` masks of all photos made consistent through the camera poses
  (``hull_vote_masks``: a voxel stays when 95% of the views that see it mask it), poses from ``--poses``;
* ``auto_refine``: the same as ``auto`` with ``refine="grabcut"``;
* ``auto_box``: with the one hint, a box on ``--hint-photo`` carried to every photo at the same place
  (``carry_box``: no poses);
* ``auto_box_poses``: the same box carried through camera poses as a 3D region (``carry_box_with_poses``),
  poses from ``--poses`` (default ``reference/transforms.json``: stands in for SfM poses, whose rotation
  error on this capture is 0.4° median).
The simulated box: the bounding box of the hint photo's reference mask, ``--box-slack`` (3%) looser on
each side, as a user drags it. Each method's rows are written as soon as it is done (the JSON accumulates
across runs; ``--methods`` reruns only those). Times are wall seconds per photo on this machine.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np

from go_core.camera import Camera
from go_core.photos.masks import grabcut_photo_mask
from go_core.scene.auto_mask import (
    AutoMaskSettings,
    auto_mask,
    carry_box,
    carry_box_with_poses,
    hull_vote_masks,
    load_segmenter,
)
from go_core.scene.object_hint import ObjectBox

METHODS = ("grabcut", "u2netp_raw", "auto", "auto_vote", "auto_refine", "auto_box", "auto_box_poses")


def load_photos(data: Path) -> tuple[list[str], list[np.ndarray], list[np.ndarray]]:
    names = sorted(p.stem for p in (data / "images").glob("*.jpg"))
    images = [cv2.cvtColor(cv2.imread(str(data / "images" / f"{n}.jpg")), cv2.COLOR_BGR2RGB) for n in names]
    refs = [
        cv2.imread(str(data / "reference" / "masks" / f"{n}.png"), cv2.IMREAD_GRAYSCALE) > 127 for n in names
    ]
    return names, images, refs


def load_cameras(path: Path, names: list[str]) -> list[Camera]:
    """Cameras of a NeRF-style transforms.json (OpenGL camera-to-world, shared intrinsics)."""
    t = json.loads(path.read_text())
    K = np.array([[t["fl_x"], 0, t["cx"]], [0, t["fl_y"], t["cy"]], [0, 0, 1.0]])
    frames = {Path(f["file_path"]).stem: f for f in t["frames"]}
    return [
        Camera.from_opengl_c2w(n, t["w"], t["h"], K, np.array(frames[n]["transform_matrix"])) for n in names
    ]


def user_box(ref: np.ndarray, slack: float) -> tuple[float, float, float, float]:
    ys, xs = np.nonzero(ref)
    x0, y0, x1, y1 = xs.min(), ys.min(), xs.max() + 1.0, ys.max() + 1.0
    dx, dy = (x1 - x0) * slack, (y1 - y0) * slack
    return x0 - dx, y0 - dy, x1 + dx, y1 + dy


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def boxes_for(method: str, args, names, images, refs) -> list:
    """Per-photo boxes of the hint methods (None: no hint)."""
    if method not in ("auto_box", "auto_box_poses"):
        return [None] * len(names)
    h = names.index(args.hint_photo)
    box = user_box(refs[h], args.box_slack)
    if method == "auto_box":
        hint = ObjectBox(args.hint_photo, box)
        return carry_box(hint, images[h].shape[:2], [im.shape[:2] for im in images])
    cams = load_cameras(args.poses or args.data / "reference" / "transforms.json", names)
    return carry_box_with_poses(box, cams[h], cams)


def run_method(method: str, args, names, images, refs, made: dict) -> dict:
    """IoU rows and summary of one method; ``made`` keeps its masks (auto_vote starts from auto's)."""
    if method == "auto_vote":
        t0 = time.time()
        base = made.get("auto") or [auto_mask(im, load_segmenter(threads=args.threads)) for im in images]
        cams = load_cameras(args.poses or args.data / "reference" / "transforms.json", names)
        masks = [m > 0.5 for m in hull_vote_masks(base, cams)]
        return summarise(dict(zip(names, masks, strict=True)), refs, names, time.time() - t0)
    segmenter = load_segmenter(threads=args.threads) if method != "grabcut" else None
    settings = AutoMaskSettings(refine="grabcut" if method == "auto_refine" else "none")
    boxes = boxes_for(method, args, names, images, refs)
    masks, t0 = {}, time.time()
    for name, image, box in zip(names, images, boxes, strict=True):
        if method == "grabcut":
            masks[name] = grabcut_photo_mask(image) > 0.5
        elif method == "u2netp_raw":
            masks[name] = segmenter(image) > 0.5
        else:
            masks[name] = auto_mask(image, segmenter, settings, box) > 0.5
    made[method] = [masks[n].astype(np.float32) for n in names]
    result = summarise(masks, refs, names, time.time() - t0)
    if method.startswith("auto_box"):
        box = user_box(refs[names.index(args.hint_photo)], args.box_slack)
        result["summary"]["hint"] = {"photo": args.hint_photo, "box": [round(float(v), 1) for v in box]}
    return result


def summarise(masks: dict, refs: list, names: list[str], seconds: float) -> dict:
    rows = {n: round(iou(masks[n], ref), 4) for n, ref in zip(names, refs, strict=True)}
    values = np.array(list(rows.values()))
    summary = {"median": round(float(np.median(values)), 4), "mean": round(float(values.mean()), 4),
               "min": round(float(values.min()), 4), "below_0.9": int((values < 0.9).sum()),
               "seconds_per_photo": round(seconds / len(names), 2)}  # fmt: skip
    return {"summary": summary, "iou": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    ap.add_argument("--hint-photo", default="DSC_0007", help="the photo the simulated user draws the box on")
    ap.add_argument("--box-slack", type=float, default=0.03)
    ap.add_argument("--poses", type=Path, default=None, help="transforms.json for auto_box_poses")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    names, images, refs = load_photos(args.data)
    result = json.loads(args.out.read_text()) if args.out.is_file() else {"methods": {}}
    result.update({"data": args.data.name, "photos": len(names), "threads": args.threads})
    made: dict = {}
    for method in args.methods:
        result["methods"][method] = run_method(method, args, names, images, refs, made)
        print(method, json.dumps(result["methods"][method]["summary"]), flush=True)
        args.out.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
