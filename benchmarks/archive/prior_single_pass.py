"""What a repair prior does in one pass, before any Gaussian is fitted to it (issue 34): where it helps, where
it harms, and whether a per-scene colour map could undo the harm.

Per dev scene, on the coarse model of the real runner's work dir (``run_pipeline(..., until="coarse")``:
cached when the dev evaluation ran there), with the prior not tuned:

* **training views**: the coarse render there (its own training photo is the truth) restored with the
  reference input as the per-scene tuning draws it (the nearest *other* training view, warped through the
  coarse depth) and as the repair loop would near that view (the view itself): PSNR inside the mask.
* **test views**: PSNR inside and outside the true silhouette of the coarse render and of the prior's
  output with the reference as the repair loop draws it (the nearest training view), with no reference
  (white, alpha 0) and with the reference occlusion-tested against the coarse model's depth at the training
  view (a warped pixel behind that depth by more than ``--occlusion-tol`` gets alpha 0); and **hull gated**:
  the prior's output with the loop's reference, but where the surface point lies inside the visual hull
  (every training mask that frames it) and the prior lowers the coverage, its object colour recomposited
  at the render's coverage (the prior may carve only outside the hull); and **union2**: the nearest view's
  warp with the second-nearest view's where the first has alpha 0 (carving needs both views to agree).
* **colour maps**: a 4x3 affine map from the prior's output to the truth inside the silhouette, applied to
  the object (blended by the prior's alpha, so the white background stays white). Fitted at the training
  views on the outputs with either reference (``ref_other`` / ``ref_own``), by least squares and pulled
  towards the identity (``RIDGES``): what a per-scene colour-only tuning could learn; and, as an upper
  bound, at the test views themselves (``oracle``).
* **tuned** (``--scenes`` only): the prior after the tune step's per-scene fine-tune of ``--tuned-steps``
  steps (the runner's tune step at default settings but ``tune.compact_steps``), with the loop's reference.

Views are restored at their full size in the square frame of the repair loop (``Frame``, ``--resolution``).

    python benchmarks/archive/prior_single_pass.py --data ../shared/data/dev --workroot W \\
        --out benchmarks/results/prior_single_pass.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np
import torch

DEV = Path(__file__).resolve().parents[3] / "shared" / "data" / "dev"
SCENES = ("alphabet_soup", "basket", "milk", "plate", "white_bowl")


def psnr(pred: np.ndarray, truth: np.ndarray, where: np.ndarray) -> float:
    """PSNR over the pixels ``where`` (bool [H, W]) of two [H, W, 3] images in [0, 1]."""
    mse = float(((pred - truth) ** 2).mean(-1)[where].mean())
    return -10.0 * np.log10(max(mse, 1e-12))


class SinglePass:
    """The prior ``name`` in one pass on renders of the coarse Gaussians ``g``, references from ``views``."""

    def __init__(self, name: str, g, views, resolution: int, tol: float) -> None:
        from go_core.compact.prior import PriorRestorer
        from go_core.compact.reference import ReferenceViews
        from go_core.repair.data import render_rgb_alpha_depth

        self.model = PriorRestorer.load(name)
        self.g, self.resolution, self.tol = g, resolution, tol
        self.refs = ReferenceViews(views)
        self.train_depth = [
            render_rgb_alpha_depth(g, v.camera, "auto", g.sh_degree)[2].numpy() for v in views
        ]

    def render(self, cam):
        from go_core.repair.data import render_rgb_alpha_depth

        return render_rgb_alpha_depth(self.g, cam, "auto", self.g.sh_degree)

    def reference(self, cam, depth, alpha, kind: str, exclude: int | None = None):
        """(rgb, alpha) float32 reference input: ``kind`` warped | none | occluded | union2."""
        h, w = depth.shape
        if kind == "none":
            return np.ones((h, w, 3), np.float32), np.zeros((h, w), np.float32)
        rgb, a = self.refs.warp(cam, depth, alpha, exclude)
        if kind == "union2" and len(self.refs.rgb) > 1:  # the second-nearest view fills the nearest's gaps
            rgb2, a2 = self.refs.warp(cam, depth, alpha, self.refs.nearest(cam, exclude))
            rgb, a = np.where(a[..., None] > 0.5, rgb, rgb2), np.maximum(a, a2)
        if kind == "occluded":
            hidden = self._hidden(cam, depth, alpha, self.refs.nearest(cam, exclude))
            rgb, a = np.where(hidden[..., None], 1.0, rgb), np.where(hidden, 0.0, a)
        return rgb.astype(np.float32), a.astype(np.float32)

    def _project(self, cam, depth: np.ndarray, alpha: np.ndarray, j: int):
        """(ut, vt, zt, ok): the pixels' surface points in training view ``j`` (reference.project)."""
        from go_core.compact import reference as R

        args = (R.intrinsics_of(cam), R.c2w_opengl(cam), self.refs.c2w[j], self.refs.intrinsics[j])
        return R.project(depth, alpha, *args, self.refs.alpha[j].shape)

    def _hidden(self, cam, depth: np.ndarray, alpha: np.ndarray, j: int) -> np.ndarray:
        """Pixels whose surface point lies behind training view ``j``'s coarse depth by more than tol."""
        from go_core.compact.reference import _bilinear

        ut, vt, zt, ok = self._project(cam, depth, alpha, j)
        return ok & (zt > _bilinear(self.train_depth[j][..., None], ut, vt)[..., 0] + self.tol)

    def inside_hull(self, cam, depth: np.ndarray, alpha: np.ndarray) -> np.ndarray:
        """Covered pixels whose surface point (``depth``) lies in every training mask that frames it."""
        from go_core.compact.reference import _bilinear

        inside = alpha > 0.5
        for j in range(len(self.refs.alpha)):
            ut, vt, _, framed = self._project(cam, depth, alpha, j)
            in_mask = framed & (_bilinear(self.refs.alpha[j][..., None], ut, vt)[..., 0] > 0.5)
            inside &= in_mask | ~framed
        return inside

    def restore(self, cam, rgb, alpha, ref) -> tuple[np.ndarray, np.ndarray]:
        """The prior's (RGB on white [H, W, 3], alpha [H, W]) for the render (rgb, alpha) with ``ref``."""
        from go_core.diffusion.frame import Frame
        from go_core.repair.data import bchw_to_hwc, framed_input, hwc_to_bchw

        frame = Frame.choose(cam.height, cam.width, alpha)
        square = framed_input(frame, self.resolution, rgb, alpha, tuple(torch.from_numpy(x) for x in ref))
        out = self.model.restore(square)
        base = torch.cat([hwc_to_bchw(rgb), alpha[None, None]], 1)
        full = bchw_to_hwc(frame.from_square(out, base)).numpy()
        return full[..., :3], full[..., 3]


RIDGES = (0.0, 0.05)  # colour-map fits: 0 = least squares; > 0 pulls the map towards the identity


def fit_colour_map(
    outputs: list[np.ndarray], truths: list[np.ndarray], masks: list[np.ndarray], ridge: float = 0.0
) -> np.ndarray:
    """The 4x3 affine map [rgb, 1] -> truth over the masked pixels: least squares plus ``ridge`` · (pixel
    count) · |map - identity|²."""
    x = np.concatenate([o[m] for o, m in zip(outputs, masks, strict=True)]).astype(np.float64)
    y = np.concatenate([t[m] for t, m in zip(truths, masks, strict=True)]).astype(np.float64)
    xa = np.c_[x, np.ones(len(x))]
    eye = np.eye(4, 3)
    reg = ridge * len(x) * np.eye(4)
    return np.linalg.solve(xa.T @ xa + reg, xa.T @ y + reg @ eye)


def apply_colour_map(m: np.ndarray, image: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """``image`` + alpha · (map(image) - image): the map acts on the object, the white background stays."""
    flat = np.c_[image.reshape(-1, 3), np.ones(image[..., 0].size)] @ m
    mapped = np.clip(flat, 0.0, 1.0).reshape(image.shape)
    return (image + alpha[..., None] * (mapped - image)).astype(np.float32)


def hull_gate(out, out_alpha, rgb, alpha, inside_hull) -> np.ndarray:
    """The prior's RGB on white, but where the surface lies inside the visual hull and the prior lowers the
    coverage, its object colour recomposited at the render's coverage (carving only outside the hull)."""
    a = np.clip(out_alpha, 1e-3, 1.0)[..., None]
    colour = np.clip((out - (1.0 - a)) / a, 0.0, 1.0)
    keep = alpha[..., None]
    recomposited = colour * keep + (1.0 - keep)
    use = (inside_hull & (out_alpha < alpha) & (out_alpha > 0.05))[..., None]
    return np.where(use, recomposited, out).astype(np.float32)


def _truth(view) -> tuple[np.ndarray, np.ndarray]:
    """A test view's photo composited on white with its mask, and the mask's inside (bool)."""
    from go_core.io.images import composite

    mask = np.asarray(view.mask, np.float32)
    return np.asarray(composite(np.asarray(view.image, np.float32), mask, 1.0)), mask > 0.5


def _split(image: np.ndarray, truth: np.ndarray, inside: np.ndarray) -> tuple[float, float]:
    """PSNR (inside, outside) the true silhouette."""
    return psnr(image, truth, inside), psnr(image, truth, ~inside)


def _summary(rows: list[tuple[float, float]]) -> dict:
    """Mean PSNR inside / outside over the views' ``_split`` rows."""
    return {"psnr_inside": _mean([r[0] for r in rows]), "psnr_outside": _mean([r[1] for r in rows])}


def _mean(values) -> float:
    return round(float(np.mean(values)), 3)


def rows_at_training_views(sp: SinglePass, scene, views) -> tuple[dict, dict]:
    """PSNR inside the mask at the training views (coarse, prior with the tuning's and the view's own
    reference) and the (outputs, truths, masks) a colour map is fitted on."""
    from go_core.io.images import composite

    rows, fit = [], {"other": ([], [], []), "own": ([], [], [])}
    for i, v in enumerate(views):
        rgb, alpha, depth = sp.render(v.camera)
        mask = np.asarray(v.mask, np.float32)
        truth = np.asarray(composite(np.asarray(scene.train[i].image, np.float32), mask, 1.0))
        inside = mask > 0.5
        d, a = depth.numpy(), alpha.numpy()
        other, _ = sp.restore(v.camera, rgb, alpha, sp.reference(v.camera, d, a, "warped", exclude=i))
        own, _ = sp.restore(v.camera, rgb, alpha, sp.reference(v.camera, d, a, "warped"))
        rows.append([psnr(rgb.numpy(), truth, inside), psnr(other, truth, inside), psnr(own, truth, inside)])
        for kind, out in (("other", other), ("own", own)):
            for lst, item in zip(fit[kind], (out, truth, inside), strict=True):
                lst.append(item)
    r = np.array(rows)
    return {
        "psnr_inside_coarse": _mean(r[:, 0]),
        "psnr_inside_prior_ref_other_view": _mean(r[:, 1]),
        "psnr_inside_prior_ref_own_view": _mean(r[:, 2]),
    }, fit


def rows_at_test_views(sp: SinglePass, scene, train_fit) -> dict:
    """Test-view PSNR inside / outside the true silhouette for coarse and the prior's reference kinds, and
    inside after a colour map fitted at the training views and at the test views (oracle)."""

    kinds = ("warped", "none", "occluded", "union2")
    rows: dict[str, list] = {k: [] for k in ("coarse", *kinds, "hull_gated")}
    outs, alphas, truths, masks = [], [], [], []
    for v, cam in zip(scene.test, scene.test_cameras, strict=True):
        rgb, alpha, depth = sp.render(cam)
        truth, inside = _truth(v)
        rows["coarse"].append(_split(rgb.numpy(), truth, inside))
        for kind in kinds:
            out, out_alpha = sp.restore(
                cam, rgb, alpha, sp.reference(cam, depth.numpy(), alpha.numpy(), kind)
            )
            rows[kind].append(_split(out, truth, inside))
            if kind == "warped":
                outs.append(out)
                alphas.append(out_alpha)
                gated = hull_gate(
                    out,
                    out_alpha,
                    rgb.numpy(),
                    alpha.numpy(),
                    sp.inside_hull(cam, depth.numpy(), alpha.numpy()),
                )
                rows["hull_gated"].append(_split(gated, truth, inside))
        truths.append(truth)
        masks.append(inside)
    result = {k: _summary(v) for k, v in rows.items()}
    fits = {"oracle": fit_colour_map(outs, truths, masks)}
    for kind, data in train_fit.items():
        for ridge in RIDGES:
            fits[f"ref_{kind}_ridge_{ridge:g}"] = fit_colour_map(*data, ridge=ridge)
    for name, m in fits.items():
        mapped = [apply_colour_map(m, o, a) for o, a in zip(outs, alphas, strict=True)]
        result[f"colour_map_{name}"] = {
            "psnr_inside": _mean([psnr(o, t, k) for o, t, k in zip(mapped, truths, masks, strict=True)]),
            "psnr_outside": _mean([psnr(o, t, ~k) for o, t, k in zip(mapped, truths, masks, strict=True)]),
            "map": np.round(m, 4).tolist(),
        }
    return result


def tuned_rows_at_test_views(sp: SinglePass, scene, scene_dir: Path, workdir: Path, args) -> dict:
    """Test-view PSNR inside / outside the silhouette of the prior tuned per scene for each of
    ``--tuned-steps`` (the runner's tune step at those steps; cached where the dev evaluation ran)."""
    from safetensors.torch import load_file

    from go_pipeline.runner import run_pipeline

    untuned = {k: v.clone() for k, v in sp.model.tuned_tensors().items()}
    result = {}
    for steps in args.tuned_steps:
        overrides = {"weights.compact_model": args.prior, "tune.compact_steps": steps}
        summary = run_pipeline(scene_dir, workdir=workdir, until="tune", overrides=overrides, quiet=True)
        sp.model.load_tuned(load_file(str(summary.step("tune").artifact_dir / "compact.safetensors")))
        rows = []
        for v, cam in zip(scene.test, scene.test_cameras, strict=True):
            rgb, alpha, depth = sp.render(cam)
            truth, inside = _truth(v)
            out, _ = sp.restore(cam, rgb, alpha, sp.reference(cam, depth.numpy(), alpha.numpy(), "warped"))
            rows.append(_split(out, truth, inside))
        result[f"tuned_{steps}"] = _summary(rows)
    sp.model.load_tuned(untuned)
    return result


def measure(scene_dir: Path, workdir: Path, args, tuned: bool = False) -> dict:
    from go_core import artifacts as art
    from go_core.repair.data import training_views
    from go_pipeline.runner import run_pipeline

    summary = run_pipeline(scene_dir, workdir=workdir, until="coarse", quiet=True)
    coarse = summary.step("coarse").artifact_dir
    scene, views = training_views(
        summary.step("scene").artifact_dir, summary.step("mask").artifact_dir, coarse
    )
    t0 = time.process_time()
    sp = SinglePass(args.prior, art.read_gaussians(coarse), views, args.resolution, args.occlusion_tol)
    train, fit = rows_at_training_views(sp, scene, views)
    test = rows_at_test_views(sp, scene, fit)
    if tuned:
        test.update(tuned_rows_at_test_views(sp, scene, scene_dir, workdir, args))
    return {"training_views": train, "test_views": test,
            "cpu_s": round(time.process_time() - t0, 1), "coarse_dir": str(coarse)}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEV)
    ap.add_argument("--scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--workroot", type=Path, default=None, help="one work dir per scene (W/<scene>)")
    ap.add_argument(
        "--run",
        nargs=3,
        action="append",
        default=[],
        metavar=("NAME", "SCENE_DIR", "WORKDIR"),
        help="another scene (a real capture) with its own work dir; may repeat",
    )
    ap.add_argument("--prior", default="go-repair-prior-2")
    ap.add_argument(
        "--tuned-steps",
        nargs="*",
        type=int,
        default=[60, 400],
        help="--scenes only: also the prior tuned per scene for these steps (tune.compact_steps)",
    )
    ap.add_argument("--resolution", type=int, default=256, help="the repair loop's compact_resolution")
    ap.add_argument("--occlusion-tol", type=float, default=0.02, help="world units")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))
    result = {
        "command": "python benchmarks/archive/prior_single_pass.py " + " ".join(os.sys.argv[1:]),
        "machine": platform.processor() or platform.machine(),
        "prior": args.prior,
        "scenes": {},
    }
    runs = [(n, args.data / n, args.workroot / n, True) for n in args.scenes]
    for name, scene_dir, workdir, tuned in runs + [(n, Path(s), Path(w), False) for n, s, w in args.run]:
        result["scenes"][name] = measure(scene_dir, workdir, args, tuned)
        print(name, json.dumps(result["scenes"][name]["test_views"]["coarse"]), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
