"""Can a rounder hull carve what the final model keeps between the training views? (issues 33 and 35)

Most of a real capture's test error is object rendered outside the photo's silhouette (docs/real_captures.md,
"Where the error lies"), and four views at about 90° leave the visual hull's horizontal cross-sections
nearly square where the object is round. This measures one shape prior that would carve those corners,
before anything is built on it: the **rounded hull** keeps a hull voxel when

    Σ_v t_v² ≤ c · n / 2,    t_v = (2u − a − b) / (b − a) ∈ [−1, 1],

where view v projects the voxel to column u of an image row whose mask run spans [a, b] (t_v = ±1 on the
silhouette's rim, 0 in the run's middle), n is the number of training views and c ≥ 1 loosens the shape
towards the hull. For n views evenly spread around an upright round object, c = 1 keeps exactly the
ellipse inscribed in the hull's cross-sections; a box keeps its corners only from c = 2.

Per capture, on the test views against their true silhouettes (alpha or mask > 0.5):
- ``hull`` / ``rounded``: the silhouette IoU of the hull and of the rounded hull (voxel centres jittered
  and splatted, the same for both), the share of the truth they leave out (``missing``: a one-sided mask
  target built on them would carve the object there) and the lowest share of a training mask they still
  cover;
- ``model`` / ``model_cut``: the final model's alpha > 0.5, and the same cut by the rounded hull: what the
  prior would add to today's model.

The final model is the repair input of the work dir's newest eval, or with ``--models`` the repair
artifact a ``repair_dev.py`` JSON names for ``--variant``. Nothing is trained.

    python benchmarks/archive/rounded_hull.py --work milk=W/milk basket=W/basket --models repair_dev.json \\
        --out benchmarks/results/rounded_hull.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from _machine import code_version  # benchmarks/ is on sys.path as a script

LOOSENESS = (1.0, 1.25, 1.5)
GRID = 128


def row_runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each pixel of a boolean mask, the first and last column of the row run it lies in (0 outside)."""
    left = np.zeros(mask.shape, np.int32)
    right = np.zeros(mask.shape, np.int32)
    for r, row in enumerate(mask):
        edges = np.diff(np.concatenate([[0], row.astype(np.int8), [0]]))
        for s, e in zip(np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0] - 1, strict=True):
            left[r, s : e + 1], right[r, s : e + 1] = s, e
    return left, right


def rim_offsets(points: np.ndarray, cameras: list, masks: list[np.ndarray]) -> np.ndarray:
    """t_v [V, N]: each point's position across its mask row run in each view, −1 and 1 on the rims."""
    out = []
    for cam, mask in zip(cameras, masks, strict=True):
        left, right = row_runs(mask > 0.5)
        uv, _ = cam.project(points)
        u = np.clip(np.floor(uv[:, 0]).astype(int), 0, cam.width - 1)
        v = np.clip(np.floor(uv[:, 1]).astype(int), 0, cam.height - 1)
        a, b = left[v, u].astype(float), right[v, u] + 1.0
        out.append(np.clip((2 * uv[:, 0] - a - b) / np.maximum(b - a, 1.0), -1, 1))
    return np.stack(out)


def splat(points: np.ndarray, cam, step: np.ndarray) -> np.ndarray:
    """Boolean silhouette of voxel centres seen by ``cam``: six jittered copies splatted, then closed."""
    from scipy import ndimage

    from go_core.seeding import numpy_rng

    image = np.zeros((cam.height, cam.width), bool)
    rng = numpy_rng(0, "rounded_hull_splat")
    for _ in range(6):
        uv, z = cam.project(points + (rng.random(points.shape) - 0.5) * step)
        ok = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        image[uv[ok, 1].astype(int), uv[ok, 0].astype(int)] = True
    return ndimage.binary_closing(image, iterations=1)


def hull_voxels(cameras: list, masks: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(voxel centres inside every training mask, their rounding score Σ t_v² / (n/2), the voxel size)."""
    from go_core.coarse.hull import hull_bounds, inside_masks

    lo, hi = hull_bounds(cameras, masks, min_views=len(cameras))
    axes = [np.linspace(lo[k], hi[k], GRID) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    points = grid[inside_masks(grid, cameras, masks).all(0)]
    score = (rim_offsets(points, cameras, masks) ** 2).sum(0) / (len(cameras) / 2)
    return points, score, (hi - lo) / (GRID - 1)


class Tally:
    """Summed pixel counts of one silhouette against the truth over the test views."""

    def __init__(self) -> None:
        self.inter = self.union = self.missing = self.truth = 0

    def add(self, pred: np.ndarray, truth: np.ndarray) -> None:
        self.inter += int((pred & truth).sum())
        self.union += int((pred | truth).sum())
        self.missing += int((truth & ~pred).sum())
        self.truth += int(truth.sum())

    def record(self) -> dict:
        return {"iou": round(self.inter / self.union, 4), "missing": round(self.missing / self.truth, 4)}


def final_model(work: Path, models: dict | None, name: str) -> Path:
    """The final model's ``gaussians.npz``: the JSON's repair artifact, else the newest eval's input."""
    if models is not None:
        return Path(models[name]) / "gaussians.npz"
    evals = [json.loads(p.read_text()) for p in (work / "artifacts" / "eval").glob("*/manifest.json")]
    newest = max(evals, key=lambda m: m["finished"])["inputs"]["repair"]
    return work / "artifacts" / "repair" / newest["key"] / "gaussians.npz"


def measure(work: Path, gaussians: Path) -> dict:
    import torch

    from go_core.gaussians import Gaussians
    from go_core.repair.data import render_rgb_alpha_depth
    from go_core.scene.artifact import load_scene_artifact

    scene = load_scene_artifact(next((work / "artifacts" / "scene").iterdir()))
    cameras, masks = scene.train_cameras, [v.mask for v in scene.train]
    points, score, step = hull_voxels(cameras, masks)
    g = Gaussians.load(gaussians).to(dtype=torch.float32)
    keys = ["hull", "model"] + [f"{kind}_c{c}" for c in LOOSENESS for kind in ("rounded", "model_cut")]
    tallies = {k: Tally() for k in keys}
    train_cover = {f"c{c}": 1.0 for c in LOOSENESS}
    for c in LOOSENESS:
        for v in scene.train:
            truth = v.mask > 0.5
            kept = splat(points[score <= c], v.camera, step)
            train_cover[f"c{c}"] = min(train_cover[f"c{c}"], float((kept & truth).sum() / truth.sum()))
    for view in scene.test:
        truth = view.mask > 0.5
        with torch.no_grad():
            model = render_rgb_alpha_depth(g, view.camera)[1].numpy() > 0.5
        tallies["hull"].add(splat(points, view.camera, step), truth)
        tallies["model"].add(model, truth)
        for c in LOOSENESS:
            rounded = splat(points[score <= c], view.camera, step)
            tallies[f"rounded_c{c}"].add(rounded, truth)
            tallies[f"model_cut_c{c}"].add(model & rounded, truth)
    return {
        "final_model": str(gaussians),
        "test_views": len(scene.test),
        "silhouettes": {k: t.record() for k, t in tallies.items()},
        "rounded_train_mask_cover_min": {k: round(v, 4) for k, v in train_cover.items()},
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", nargs="+", required=True, help="NAME=WORKDIR")
    ap.add_argument("--models", type=Path, help="a repair_dev.py JSON naming each scene's repair artifact")
    ap.add_argument("--variant", default="full")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    named = None
    if args.models:
        scenes = json.loads(args.models.read_text())["scenes"]
        named = {n: s["variants"][args.variant]["repair_dir"] for n, s in scenes.items()}
    result = json.loads(args.out.read_text()) if args.out.is_file() else {"captures": {}}
    for item in args.work:
        name, work = item.split("=", 1)
        start = time.process_time()
        gaussians = final_model(Path(work), named if named and name in named else None, name)
        result["captures"][name] = measure(Path(work), gaussians) | {
            "cpu_s": round(time.process_time() - start)
        }
        print(name, json.dumps(result["captures"][name]["silhouettes"]), flush=True)
    command = "python benchmarks/archive/rounded_hull.py " + " ".join(sys.argv[1:])
    result.setdefault("commands", []).append(f"{command} (code {code_version()})")
    result.update(looseness=list(LOOSENESS), grid=GRID)
    args.out.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
