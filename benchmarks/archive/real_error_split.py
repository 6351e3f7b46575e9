"""Where the test error of a real capture lies (issue 33): the final model of a `real_captures.py` work dir,
its squared error on white split by silhouette agreement, and per test view against the angle to the
nearest training camera.

Pixels of each test view fall in one of four classes by the photo's mask (> 0.5) and the render's alpha
(> 0.5): `both` (object in both: appearance error), `mask_only` (the model misses object: holes, thin
parts), `render_only` (the model has object where the photo has none: a bulge, floaters) and `neither`.
Each class's share of the summed squared error says whether shape or appearance limits the PSNR. The
`oracle_silhouette_psnr` replaces only the render's alpha by the photo's mask (colour kept where the render
has alpha ≥ 0.05, white elsewhere): how far a perfect silhouette alone would go. `render_only` error is
also split by the distance outside the photo's outline (≤ 3 px: the edge; beyond: a bulge), and each view's
silhouette is set beside the visual hull's (the mesh step's `hull_mesh.ply`, filled as eval fills meshes):
the hull is the largest shape the four training silhouettes allow, so the excess the model keeps inside it
is shape the photos leave open.

The run is the cached one of `real_captures.py` (same work dir, variant and seed: nothing retrains).

    python benchmarks/archive/real_error_split.py --data ../shared/data --captures real/blowtorch \\
        --workroot W --variant aniso --out benchmarks/results/real_error_split.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from real_captures import parse_variant, scene_folder

CLASSES = ("both", "mask_only", "render_only", "neither")


def nearest_training_angle(cam, train_cams, centre: np.ndarray) -> float:
    """Degrees between the view's direction from ``centre`` and the closest training view's."""

    def direction(c) -> np.ndarray:
        v = c.center - centre
        return v / np.linalg.norm(v)

    d = direction(cam)
    return float(min(np.degrees(np.arccos(np.clip(d @ direction(t), -1, 1))) for t in train_cams))


def split_view(
    render: np.ndarray, alpha: np.ndarray, photo: np.ndarray, mask: np.ndarray, hull: np.ndarray
) -> dict:
    """Pixels and summed squared error per pixel class, the view's PSNR and its PSNR with the photo's
    silhouette, and the hull's excess (object where the photo has none) and IoU. The model's excess and
    IoU follow from the classes (``model_silhouette``)."""
    import cv2

    from go_core.io.images import composite
    from go_core.metrics.error_split import split_errors

    truth = composite(photo, mask)
    m, a = mask > 0.5, alpha > 0.5
    classes = {"both": m & a, "mask_only": m & ~a, "render_only": ~m & a, "neither": ~m & ~a}
    outside = cv2.distanceTransform((~m).astype(np.uint8), cv2.DIST_L2, 3)
    classes_and_edge = {**classes, "render_only_edge": classes["render_only"] & (outside <= 3)}
    split = split_errors(render, truth, classes_and_edge)
    a3 = alpha[..., None]
    colour = np.where(a3 >= 0.05, (render - (1.0 - a3)) / np.maximum(a3, 0.05), 1.0)
    oracle = composite(np.clip(colour, 0, 1), mask)
    mse = sum(split[k]["sse"] for k in CLASSES) / mask.size
    mse_oracle = float(((oracle - truth) ** 2).mean())
    return {
        "render_only_sse_edge": split.pop("render_only_edge")["sse"],
        "hull": {
            "excess_px": int((hull & ~m).sum()),
            "iou": float((hull & m).sum() / max((hull | m).sum(), 1)),
        },
        "psnr": -10 * np.log10(max(mse, 1e-12)),
        "oracle_silhouette_psnr": -10 * np.log10(max(mse_oracle, 1e-12)),
        "sse": {k: v["sse"] for k, v in split.items()},
        "pixels": {k: v["pixels"] for k, v in split.items()},
    }


def model_silhouette(pixels: dict) -> tuple[int, float]:
    """The model's excess pixels and silhouette IoU from a view's pixel classes."""
    union = pixels["both"] + pixels["mask_only"] + pixels["render_only"]
    return pixels["render_only"], pixels["both"] / max(union, 1)


def measure(scene_dir: Path, workdir: Path, overrides: dict) -> dict:
    """Per-view split of the cached final model of ``workdir``."""
    import torch

    from go_core import artifacts as art
    from go_core.camera import look_at_point
    from go_core.mesh.files import read_ply
    from go_core.metrics.geometry import silhouette
    from go_core.render import render_camera
    from go_pipeline.runner import run_pipeline

    summary = run_pipeline(scene_dir, workdir=workdir, overrides=overrides, until="eval", quiet=True)
    scene = art.read_scene(summary.step("scene").artifact_dir)
    final = art.final_model(summary.step("coarse").artifact_dir, summary.step("repair").artifact_dir)
    g = art.read_gaussians(final.folder)
    hull = read_ply(Path(summary.step("mesh").artifact_dir) / "hull_mesh.ply")
    train_cams = [v.camera for v in scene.train]
    centre = look_at_point(train_cams)
    views = []
    with torch.no_grad():
        for view in scene.test:
            out = render_camera(g, view.camera, background=torch.ones(3))
            row = split_view(
                out.rgb[0].clamp(0, 1).numpy().astype(np.float64),
                out.alpha[0, ..., 0].numpy().astype(np.float64),
                np.asarray(view.image, dtype=np.float64),
                np.asarray(view.mask, dtype=np.float64),
                silhouette(hull, view.camera) > 0.5,
            )
            row["name"] = view.name
            row["angle_to_nearest_train_deg"] = nearest_training_angle(view.camera, train_cams, centre)
            views.append(row)
    total = {k: sum(v["sse"][k] for v in views) for k in CLASSES}
    s = sum(total.values())
    return {
        "model": final.source,
        "sse_share": {k: round(total[k] / s, 4) for k in CLASSES},
        "render_only_edge_share": round(sum(v["render_only_sse_edge"] for v in views) / s, 4),
        "excess_px": {
            "model": int(sum(model_silhouette(v["pixels"])[0] for v in views)),
            "hull": int(sum(v["hull"]["excess_px"] for v in views)),
        },
        "mean_iou": {
            "model": float(np.mean([model_silhouette(v["pixels"])[1] for v in views])),
            "hull": float(np.mean([v["hull"]["iou"] for v in views])),
        },
        "mean_psnr": float(np.mean([v["psnr"] for v in views])),
        "mean_oracle_silhouette_psnr": float(np.mean([v["oracle_silhouette_psnr"] for v in views])),
        "views": views,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--captures", nargs="+", required=True)
    ap.add_argument("--workroot", type=Path, required=True)
    ap.add_argument("--variant", default="defaults", help="NAME[:step.param=value,...] as real_captures.py")
    ap.add_argument("--photo-size", type=int, default=400)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    name, overrides = parse_variant(args.variant)
    result = json.loads(args.out.read_text()) if args.out.exists() else {"captures": {}}
    for capture in args.captures:
        scene_dir = scene_folder(capture, args.data, args.workroot, args.photo_size)
        workdir = args.workroot / capture.replace("/", "_") / name
        entry = measure(scene_dir, workdir, overrides)
        result["captures"].setdefault(capture, {})[name] = entry
        psnr, oracle = entry["mean_psnr"], entry["mean_oracle_silhouette_psnr"]
        print(capture, name, entry["sse_share"], f"PSNR {psnr:.2f}, oracle silhouette {oracle:.2f}")
    args.out.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
