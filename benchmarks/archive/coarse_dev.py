"""Coarse-stage benchmark on the dev scenes: test-view PSNR/SSIM, Gaussian count and CPU seconds per variant.

Every variant starts from the coarse params of pipeline.yaml (``--profile`` picks a profile, e.g. ``paper``)
and overrides a few (same iteration budget each):
  hull          the profile's settings: visual-hull init, floater elimination with the default λe schedule
  random        ablation: vanilla-3DGS random init (no masks used for the init)
  hull_paper    floater schedule "paper" (λe 1 → 0) instead of the default "code" (1 → 2.33)
  hull_code     floater schedule "code" explicitly
  no_floaters   ablation: floater elimination off
  drop / outside / mask10 / aniso / opacity   one regulariser on (see VARIANTS for the weights)
  no_drop / no_outside / no_aniso / no_opacity  one regulariser off
Variants join with "+" (e.g. ``drop+aniso``: both overrides).

``--iterations N`` is the coarse budget knob (``coarse.iterations``): every step-based schedule (densification
window and interval, opacity reset, SH raise, floater window and interval, position-lr decay) is scaled by
N / ``coarse.schedule_iterations`` (10 000) in ``CoarseConfig.scaled_schedule``, so the run is a
compressed version of the paper's (opacity resets off when their period falls below 500). Test renders use
a white background; the ground truth is the test photo composited on white with its mask (paper protocol).
The training and the scores are ``benchmarks/_lib/coarse.py``'s (shared with ``geometry_dev.py``).

    python benchmarks/archive/coarse_dev.py --iterations 2000 --variants hull random \
        --out benchmarks/results/coarse_dev.json
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/ (_lib.coarse), from archive/
from _lib.coarse import (  # noqa: E402
    DEV,
    coarse_params,
    evaluate,
    hull_params,
    parse_overrides,
    train_coarse,
)

from go_core.scene.loader import load_scene  # noqa: E402

PAPER_ITERS = 10_000
VARIANTS = {
    "hull": {"init": "hull", "params": {}},
    "random": {"init": "random", "params": {}},
    "hull_paper": {"init": "hull", "params": {"floater_schedule": "paper"}},
    "hull_code": {"init": "hull", "params": {"floater_schedule": "code"}},
    "no_floaters": {"init": "hull", "params": {"floaters": False}},
    # regularisers (benchmarks/results/coarse_dev.md, "Sparse-view regularisers")
    "drop": {"init": "hull", "params": {"drop_gamma": 0.2}},
    "outside": {"init": "hull", "params": {"lambda_outside": 0.1}},
    "mask10": {"init": "hull", "params": {"lambda_mask": 0.1}},
    "aniso": {"init": "hull", "params": {"lambda_anisotropy": 0.01}},
    "opacity": {"init": "hull", "params": {"lambda_opacity": 0.01}},
    "drop4": {"init": "hull", "params": {"drop_gamma": 0.4}},
    "opacity5": {"init": "hull", "params": {"lambda_opacity": 0.05}},
    "sh0": {"init": "hull", "params": {"sh_degree": 0}},
    "sh1": {"init": "hull", "params": {"sh_degree": 1}},
    "no_drop": {"init": "hull", "params": {"drop_gamma": 0.0}},
    "no_outside": {"init": "hull", "params": {"lambda_outside": 0.0}},
    "no_aniso": {"init": "hull", "params": {"lambda_anisotropy": 0.0}},
    "no_opacity": {"init": "hull", "params": {"lambda_opacity": 0.0}},
    # real captures (issue 33, docs/coarse.md "Real captures")
    "inside": {"init": "hull", "params": {"lambda_inside": 0.1}},
    "color": {"init": "hull", "params": {"color_correction": True}},
    "screen_px": {"init": "hull", "params": {"max_screen_fraction": 0.0}},
    "white_bg": {"init": "hull", "params": {"random_background": False}},
}


def variant_spec(name: str) -> dict:
    """A variant, or several joined with "+" (their overrides merged; a random init if any asks for it)."""
    parts = [VARIANTS[n] for n in name.split("+")]
    init = "random" if any(p["init"] == "random" for p in parts) else "hull"
    return {"init": init, "params": {k: v for p in parts for k, v in p["params"].items()}}


def train_variant(scene, name: str, iterations: int, seed: int, extra: dict, **kwargs):
    """Train one variant on one scene (``train_coarse``'s keyword arguments: ``random_points``, ``base``,
    ``hull``). Returns (Gaussians, training stats, a dict of params and seconds)."""
    spec = variant_spec(name)
    return train_coarse(scene, spec["init"], iterations, seed, {**spec["params"], **extra}, **kwargs)


def run_variant(scene, name: str, iterations: int, seed: int, extra: dict, **kwargs) -> dict:
    """One variant on one scene (``train_variant``'s keyword arguments), scored on the test views."""
    g, stats, run = train_variant(scene, name, iterations, seed, extra, **kwargs)
    metrics = evaluate(g, scene)
    return {
        **metrics,
        "gaussians": stats.final_count,
        "max_gaussians_seen": stats.max_count,
        "floaters_removed": stats.floaters_removed,
        "densify": stats.densify,
        **run,
    }


def summarise(result: dict) -> dict:
    """Add the hull − random margins and the floater-schedule comparison to a result dict."""
    margins, code_vs_paper = [], []
    for s in result["scenes"].values():
        if "hull" in s and "random" in s:
            s["hull_minus_random_db"] = round(s["hull"]["psnr"] - s["random"]["psnr"], 3)
            margins.append(s["hull_minus_random_db"])
        if "hull" in s and "hull_paper" in s:
            code_vs_paper.append(s["hull"]["psnr"] - s["hull_paper"]["psnr"])
    if margins:
        result["min_hull_minus_random_db"] = min(margins)
        result["target_hull_plus_5db_met"] = bool(min(margins) >= 5.0)
    if code_vs_paper:
        result["mean_code_minus_paper_floater_schedule_db"] = round(float(np.mean(code_vs_paper)), 3)
    result["dev_means"] = dev_means(result)
    return result


def merge(paths: list[Path], out: Path) -> dict:
    """Combine per-scene result files (e.g. from parallel runs) into one."""
    parts = [json.loads(p.read_text()) for p in paths]
    result = {k: v for k, v in parts[0].items() if k != "scenes"}
    result["scenes"] = {}
    for part in parts:
        for name, scene in part["scenes"].items():
            result["scenes"].setdefault(name, {}).update(scene)
    result = summarise(result)
    out.write_text(json.dumps(result, indent=2, sort_keys=True))
    return result


def dev_means(result: dict) -> dict[str, dict[str, float]]:
    """Per variant, the mean over the scenes that ran it of PSNR, SSIM, LPIPS*, Gaussians and CPU seconds."""
    keys = ("psnr", "ssim", "lpips_star", "gaussians", "coarse_cpu_s")
    runs: dict[str, list[dict]] = {}
    for scene in result["scenes"].values():
        for variant, r in scene.items():
            if isinstance(r, dict) and "psnr" in r:
                runs.setdefault(variant, []).append(r)
    return {
        v: {
            "scenes": len(rs),
            **{k: float(np.mean([r[k] for r in rs])) for k in keys if all(k in r for r in rs)},
        }
        for v, rs in runs.items()
    }


def markdown_table(result: dict) -> str:
    """Per scene and variant: PSNR / SSIM / LPIPS* / Gaussians / coarse CPU s, then the dev means."""
    lines = [
        "| scene | variant | PSNR | SSIM | LPIPS* | Gaussians | CPU s |",
        "|---|---|---|---|---|---|---|",
    ]

    def row(scene: str, variant: str, r: dict) -> str:
        lp = f"{r['lpips_star']:.2f}" if "lpips_star" in r else "–"
        return (
            f"| {scene} | {variant} | {r['psnr']:.2f} | {r['ssim']:.4f} | {lp} | {r['gaussians']:.0f} "
            f"| {r['coarse_cpu_s']:.0f} |"
        )

    for name, scene in sorted(result["scenes"].items()):
        for variant, r in scene.items():
            if isinstance(r, dict) and "psnr" in r:
                lines.append(row(name, variant, r))
    for variant, m in dev_means(result).items():
        lines.append(row(f"**mean ({m['scenes']})**", variant, m))
    return "\n".join(lines)


def with_train_masks(scene, how: str):
    """``scene`` with its training masks as given, thresholded at ½, or thresholded and then smoothed."""
    from dataclasses import replace

    from go_core.scene.mask_edges import smooth_binary_edges

    if how == "given":
        return scene
    for i, v in enumerate(scene.train):
        binary = (np.asarray(v.mask) >= 0.5).astype(np.float32)
        scene.train[i] = replace(v, mask=smooth_binary_edges(binary) if how == "smooth" else binary)
    return scene


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DEV)
    ap.add_argument("--scenes", nargs="*", default=None)
    ap.add_argument("--iterations", type=int, default=PAPER_ITERS)
    ap.add_argument(
        "--variants",
        nargs="*",
        default=["hull", "random"],
        help=f"any of {sorted(VARIANTS)} or several joined by +",
    )
    ap.add_argument("--profile", default=None, help="pipeline.yaml profile the coarse params come from")
    ap.add_argument("--max-size", type=int, default=0, help="downscale images to this longest side (0: keep)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: leave)")
    ap.add_argument("--set", nargs="*", default=[], help="extra coarse params, e.g. max_gaussians=50000")
    ap.add_argument("--hull-set", nargs="*", default=[], help="hull params, e.g. num_points=10000")
    ap.add_argument(
        "--random-points",
        type=int,
        default=20_000,
        help="points of the random-init variant (20 000 = the hull's count; vanilla 3DGS uses 100 000)",
    )
    ap.add_argument(
        "--train-masks",
        choices=["given", "binary", "smooth"],
        default="given",
        help="binary: the training masks thresholded at 0.5 (as a real capture's); smooth: binary, then "
        "each outline pixel's estimated coverage (mask.binary_edges=smooth)",
    )
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/coarse_dev.json"))
    ap.add_argument("--merge", nargs="*", type=Path, default=None, help="merge these result files into --out")
    ap.add_argument("--table", type=Path, default=None, help="print a result file as a markdown table")
    return ap


def main(argv=None) -> int:
    ap = _parser()
    args = ap.parse_args(argv)
    if args.table:
        print(markdown_table(json.loads(args.table.read_text())))
        return 0
    if args.merge:
        res = merge(args.merge, args.out)
        print(json.dumps({k: v for k, v in res.items() if k != "scenes"}, indent=2))
        return 0
    if args.threads:
        torch.set_num_threads(args.threads)
    extra = parse_overrides(args.set)
    hull = {**hull_params(args.profile), **parse_overrides(args.hull_set)}
    scenes = args.scenes or sorted(
        p.name for p in args.data.iterdir() if (p / "transforms_train.json").exists()
    )
    result = {
        "benchmark": "coarse_dev",
        "iterations": args.iterations,
        "scaled_schedule": args.iterations != PAPER_ITERS,
        "schedule_scaling": "go_core.coarse.settings.CoarseConfig.scaled_schedule",
        "max_size": args.max_size,
        "train_masks": args.train_masks,
        "random_points": args.random_points,
        "hull": {k: hull[k] for k in ("num_points", "opacity")},
        "profile": args.profile or "default",
        "torch_threads": torch.get_num_threads(),
        "machine": platform.processor() or platform.machine(),
        "scenes": {},
    }
    # read once: edits to pipeline.yaml while the benchmark runs don't leak into its later runs
    base = coarse_params(args.profile, args.iterations)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    for name in scenes:
        scene = with_train_masks(load_scene(args.data / name, max_size=args.max_size), args.train_masks)
        result["scenes"][name] = {"resolution": [scene.train[0].camera.width, scene.train[0].camera.height]}
        for variant in args.variants:
            r = run_variant(
                scene,
                variant,
                args.iterations,
                args.seed,
                extra,
                random_points=args.random_points,
                base=base,
                hull=hull,
            )
            result["scenes"][name][variant] = r
            print(
                f"{name:14s} {variant:12s} PSNR {r['psnr']:6.2f}  SSIM {r['ssim']:.4f}  "
                f"LPIPS* {r.get('lpips_star', float('nan')):5.2f}  "
                f"N {r['gaussians']:6d}  cpu {r['coarse_cpu_s']:7.1f}s  wall {r['coarse_wall_s']:7.1f}s",
                flush=True,
            )
            args.out.write_text(json.dumps(result, indent=2, sort_keys=True))
        args.out.write_text(json.dumps(summarise(result), indent=2, sort_keys=True))
    result = summarise(result)
    args.out.write_text(json.dumps(result, indent=2, sort_keys=True))
    print(json.dumps({k: v for k, v in result.items() if k != "scenes"}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
