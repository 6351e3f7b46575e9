"""A folder of photos, end to end (issue 32), on a photo set with a reference/ folder (evaluation only).

``--part product``: copies the set's ``images/`` ALONE into an empty folder and times ``go-pipeline run`` on
it from an empty work dir (run it under ``--whole`` for the 2-core figure), then scores
what the product made against ``reference/``: photos registered, rotation error of every posed photo after a
similarity alignment of the camera centres (median, max), the IoU of its masks, the chosen training views,
the test metrics, the time of every step.

``--part reference``: the same training views and test photos, with the reference masks (as alpha) and
poses, as a NeRF-synthetic folder at the same photo size, run with the same settings: the PSNR gap between
the two is the cost of the product's own masks and poses.

    python benchmarks/photos.py --part product
    python benchmarks/photos.py --part reference
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

DATA = (
    Path(__file__).resolve().parents[2] / "shared" / "data" / "photos" / "ethiopian_head"
)  # ../shared beside the checkout
OUT = Path(__file__).resolve().parent / "results" / "photos_ethiopian_head.json"


def _cli(scene: Path, sets: list[str], log: Path, until: str = "") -> tuple[int, float]:
    cmd = [sys.executable, "-m", "go_pipeline.cli", "run", str(scene)] + (["--until", until] if until else [])
    for s in sets:
        cmd += ["--set", s]
    start = time.perf_counter()
    with open(log, "w") as f:
        rc = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT).returncode
    return rc, time.perf_counter() - start


def last_run(folder: Path) -> dict:
    """The ``.go/runs/last.json`` record of the last run in ``folder``."""
    return json.loads((folder / ".go" / "runs" / "last.json").read_text())


def step_artifact(last: dict, step: str) -> Path | None:
    """The artifact folder of ``step`` in a run record (None when the step made none)."""
    return next(
        (Path(s["artifact_dir"]) for s in last["steps"] if s["name"] == step and s.get("artifact_dir")), None
    )


def _run_facts(scene: Path) -> dict:
    """Per-step wall time and status, the test metrics and the scene artifact folder of the last run."""
    last = last_run(scene)
    steps = {
        s["name"]: {"status": s["status"], "wall_s": round(s.get("wall_s") or 0.0, 1)} for s in last["steps"]
    }
    metrics_path = scene / ".go" / "outputs" / "metrics.json"
    metrics = json.loads(metrics_path.read_text()) if metrics_path.is_file() else {}
    return {
        "wall_s": round(last.get("wall_s") or 0.0, 1),
        "steps": steps,
        "metrics": metrics.get("mean"),
        "model": metrics.get("model"),
        "scene_artifact": step_artifact(last, "scene"),
    }


def _reference(data: Path) -> dict:
    from go_core.camera import Camera

    ref = json.loads((data / "reference" / "transforms.json").read_text())
    K = np.array([[ref["fl_x"], 0, ref["cx"]], [0, ref["fl_y"], ref["cy"]], [0, 0, 1.0]])
    cams = {}
    for f in ref["frames"]:
        name = Path(f["file_path"]).name
        cams[name] = Camera.from_opengl_c2w(name, ref["w"], ref["h"], K, np.asarray(f["transform_matrix"]))
    return cams


def rotation_errors(estimated: dict, reference: dict) -> dict[str, float]:
    """Degrees, per photo: estimated vs reference rotation after the similarity of the camera centres."""
    from go_core.poses.similarity import umeyama

    names = sorted(estimated)
    sim = umeyama(
        np.stack([estimated[n].center for n in names]), np.stack([reference[n].center for n in names])
    )
    out = {}
    for n in names:
        r = sim.camera(estimated[n]).world_to_cam[:3, :3] @ reference[n].world_to_cam[:3, :3].T
        out[n] = float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))
    return out


def mask_ious(scene_artifact: Path, data: Path) -> dict[str, float]:
    """IoU of each view's mask (photo size, undistorted) with the reference mask scaled to that size."""
    import cv2

    from go_core.io.images import read_mask
    from go_core.scene.artifact import load_scene_artifact

    scene = load_scene_artifact(scene_artifact)
    out = {}
    for v in scene.train + scene.test:
        ref = read_mask(data / "reference" / "masks" / f"{v.name}.png")
        ref = cv2.resize(ref, (v.camera.width, v.camera.height), interpolation=cv2.INTER_AREA) > 0.5
        own = v.mask > 0.5
        out[v.name] = float((ref & own).sum() / max(1, (ref | own).sum()))
    return out


def product(args) -> dict:
    from go_core.scene.artifact import load_scene_cameras

    work = Path(args.tmp) / "product"
    shutil.rmtree(work, ignore_errors=True)
    scene = work / "photos"
    shutil.copytree(args.data / "images", scene / "images")  # the images alone: no reference/
    rc, wall = _cli(scene, args.set, work / "run.log", args.until)
    command = "go-pipeline run PHOTOS" + "".join(f" --set {s}" for s in args.set)
    result = {"command": command + (f" --until {args.until}" if args.until else ""), "rc": rc}
    result["wall_s"] = round(wall, 1)
    if rc != 0:
        result["error"] = (work / "run.log").read_text().strip().splitlines()[-1]
        return result
    facts = _run_facts(scene)
    art = facts.pop("scene_artifact")
    photos = json.loads((art / "photos.json").read_text())
    train, test = load_scene_cameras(art)
    cams = {c.name: c for c in train + test}
    rot = rotation_errors(cams, _reference(args.data))
    ious = mask_ious(art, args.data)
    sfm = photos["sfm"]
    result.update(facts)
    result.update(
        {
            "photos": photos["photos"],
            "registered": sfm["registered"],
            "not_registered": sfm["not_registered"],
            "sfm_features": sfm["features"],
            "sfm_mean_reprojection_px": sfm["mean_reprojection_px"],
            "sfm_attempts": sfm["attempts"],
            "rotation_error_deg": {"median": float(np.median(list(rot.values()))), "max": max(rot.values())},
            "rotation_error_per_photo": {k: round(v, 3) for k, v in rot.items()},
            "masks": photos["masks"],
            "mask_iou": {
                "median": float(np.median(list(ious.values()))),
                "mean": float(np.mean(list(ious.values()))),
                "min": min(ious.values()),
            },
            "train_views": photos["views"]["train"],
            "why": photos["views"]["why"],
            "test_views": [c.name for c in test],
            "photo_size": max(train[0].width, train[0].height),
        }
    )
    return result


def _nerf_frames(names, cams, data, folder: Path, split: str, size: int) -> list[dict]:
    """RGBA PNGs (photo + reference mask as alpha) at ``size`` and their frames (OpenGL c2w)."""
    import cv2

    from go_core.io.images import read_image, read_mask, write_png

    frames = []
    for n in names:
        rgb = read_image(data / "images" / f"{n}.jpg")[..., :3]
        mask = read_mask(data / "reference" / "masks" / f"{n}.png")
        rgba = np.concatenate([rgb, mask[..., None]], 2)
        h, w = rgba.shape[:2]
        s = size / max(h, w)
        rgba = cv2.resize(rgba, (round(w * s), round(h * s)), interpolation=cv2.INTER_AREA)
        write_png(folder / split / f"{n}.png", rgba)
        frames.append({"file_path": f"./{split}/{n}", "transform_matrix": cams[n].opengl_c2w.tolist()})
    return frames


def reference(args, product_result: dict) -> dict:
    work = Path(args.tmp) / "reference"
    shutil.rmtree(work, ignore_errors=True)
    scene = work / "scene"
    cams = _reference(args.data)
    first = next(iter(cams.values()))
    angle = 2 * math.atan(first.width / (2 * first.K[0, 0]))
    size = product_result["photo_size"]
    for split, names in (("train", product_result["train_views"]), ("test", product_result["test_views"])):
        frames = _nerf_frames(names, cams, args.data, scene, split, size)
        (scene / f"transforms_{split}.json").write_text(
            json.dumps({"camera_angle_x": angle, "frames": frames})
        )
    rc, wall = _cli(scene, args.set, work / "run.log")
    result = {"rc": rc, "wall_s": round(wall, 1), "what": "same train/test photos, reference masks + poses"}
    if rc != 0:
        result["error"] = (work / "run.log").read_text().strip().splitlines()[-1]
        return result
    facts = _run_facts(scene)
    facts.pop("scene_artifact")
    result.update(facts)
    return result


def table(doc: dict) -> str:
    """The markdown table of docs/photos.md from the JSON."""
    rows = [
        "| run | photos posed | rotation error median / max (deg) | mask IoU median / mean / min | "
        "training views | PSNR / SSIM / LPIPS* | wall (s, 2 cores) |",
        "|---|---|---|---|---|---|---|",
    ]
    for label, entry in doc["runs"].items():
        p = entry.get("product", {})
        if "registered" not in p:
            rows.append(f"| {label} | failed: {p.get('error', '?')} | | | | | {p.get('wall_s', '')} |")
            continue
        rot, iou, m = p["rotation_error_deg"], p["mask_iou"], p.get("metrics") or {}
        metrics = f"{m['psnr']:.2f} / {m['ssim']:.3f} / {m['lpips_star']:.1f}" if m else "-"
        rows.append(
            f"| {label}: own masks + SfM | {p['registered']}/{p['photos']} "
            f"| {rot['median']:.2f} / {rot['max']:.2f} "
            f"| {iou['median']:.3f} / {iou['mean']:.3f} / {iou['min']:.3f} | {', '.join(p['train_views'])} "
            f"| {metrics} | {p['wall_s']} |"
        )
        r = entry.get("reference", {})
        if r.get("metrics"):
            m = r["metrics"]
            rows.append(
                f"| {label}: reference masks + poses | - | - | - | same "
                f"| {m['psnr']:.2f} / {m['ssim']:.3f} / {m['lpips_star']:.1f} | {r['wall_s']} |"
            )
    return "\n".join(rows)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--part", choices=["product", "reference", "table"], required=True)
    p.add_argument("--data", type=Path, default=DATA)
    p.add_argument("--tmp", type=Path, default=Path("/tmp/go-photos-bench"))
    p.add_argument("--set", action="append", default=[], help="STEP.PARAM=VALUE for both runs")
    p.add_argument("--out", type=Path, default=OUT)
    p.add_argument("--label", default="defaults", help="the key of this configuration in the JSON")
    p.add_argument("--until", default="", help="product: stop after this step (scene: masks and SfM only)")
    args = p.parse_args()
    doc = json.loads(args.out.read_text()) if args.out.is_file() else {"data": str(args.data), "runs": {}}
    if args.part == "table":
        print(table(doc))
        return 0
    entry = doc["runs"].setdefault(args.label, {})
    if args.part == "product":
        entry["product"] = product(args)
    else:
        entry["reference"] = reference(args, entry["product"])
        own, ref = entry["product"].get("metrics"), entry["reference"].get("metrics")
        if own and ref:
            entry["psnr_gap_db"] = round(ref["psnr"] - own["psnr"], 3)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")
    print(json.dumps({k: v for k, v in entry.items()}, indent=1)[:3000])
    return 0


if __name__ == "__main__":
    sys.exit(main())
