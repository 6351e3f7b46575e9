"""Geometry on the dev scenes: Chamfer-L1, F@1%/2%, normal consistency and test-view silhouette IoU of the
visual hull's mesh and of the coarse model's mesh against each scene's ground-truth mesh (docs/geometry.md).

Per scene: the hull step's Gaussians and a coarse model trained with pipeline.yaml's defaults (hull and
coarse params, ``--iterations`` to change the budget) are made once and kept under ``--cache`` (a rerun
measures again without training: the runs are resumable one scene at a time); the meshes are made with
the mesh step's defaults (go_core.mesh.extract) and timed. The repair chain is not run here (too costly on
the shared 2-core machine): the coarse mesh stands in for the final one, and the JSON says so.

    python benchmarks/geometry_dev.py --scenes milk --stage train
    python benchmarks/geometry_dev.py --stage measure \\
        --out benchmarks/results/geometry_dev.json

A training change (issue #35, item 4) is a named variant with coarse param overrides, cached apart:

    python benchmarks/geometry_dev.py --iterations 1000 --variant dn --coarse lambda_depth_normal=0.05 \\
        --out /tmp/geometry_dev_dn.json

Each scene also gets the coarse model's test-view PSNR / SSIM / LPIPS* on white (``coarse_images``), so a
change is judged on geometry and on images together.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import torch
from _lib.coarse import (
    DEV,
    coarse_params,
    evaluate,
    hull_params,
    parse_overrides,
    step_params_from_yaml,
    train_coarse,
)

from go_core.coarse.hull import hull_bounds
from go_core.gaussians import Gaussians
from go_core.mesh.extract import mesh_from_gaussians
from go_core.mesh.files import read_mesh_npz, write_glb, write_ply
from go_core.mesh.hull_mesh import hull_mesh
from go_core.mesh.settings import MeshSettings
from go_core.metrics.geometry import score_meshes
from go_core.scene.loader import load_scene
from go_pipeline.pipeline import step_params

SCENES = ("alphabet_soup", "basket", "milk", "plate", "white_bowl")
KEYS = ("chamfer_l1", "fscore_1pct", "fscore_2pct", "normal_consistency", "silhouette_iou")


def train(scene_dir: Path, cache: Path, iterations: int | None, seed: int, extra: dict) -> Path:
    """The coarse model of one scene under ``cache`` (trained when missing), ``extra`` coarse overrides."""
    path = cache / scene_dir.name / "coarse_gaussians.npz"
    if path.is_file():
        return path
    scene = load_scene(scene_dir)
    base = coarse_params(None, iterations) if iterations else step_params_from_yaml("coarse", None)
    g, stats, run = train_coarse(
        scene, "hull", base["iterations"], seed, extra, base=base, hull=hull_params(None)
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    g.save(path)
    run["gaussians"] = stats.final_count
    (path.parent / "coarse_run.json").write_text(json.dumps(run, indent=2, sort_keys=True, default=str))
    return path


def mesh_params(overrides: list[str]):
    """The mesh step's params (its defaults, ``KEY=VALUE`` overrides parsed as YAML scalars, checked)."""
    import yaml

    values = {k: yaml.safe_load(v) for k, v in (o.split("=", 1) for o in overrides)}
    return step_params("go_pipeline.steps.mesh", values)


def measure(scene_dir: Path, cache: Path, seed: int, samples: int, export_dir: Path | None, params) -> dict:
    """Meshes of one scene (hull, coarse), their seconds and their scores against the ground truth."""
    scene = load_scene(scene_dir)
    cams, masks = scene.train_cameras, [v.mask for v in scene.train]
    g = Gaussians.load(cache / scene_dir.name / "coarse_gaussians.npz").to(dtype=torch.float32)
    settings = MeshSettings(**{k: getattr(params, k) for k in MeshSettings.__dataclass_fields__})
    t0 = time.perf_counter()
    box = hull_bounds(cams, masks, min_views=len(cams))
    coarse, info = mesh_from_gaussians(g, cams, box, settings, masks)
    t1 = time.perf_counter()
    hull = hull_mesh(cams, masks, params.hull_resolution)
    t2 = time.perf_counter()
    if export_dir is not None:  # the files the step would write, for a look (and their cost)
        write_ply(coarse, export_dir / scene_dir.name / "model_mesh.ply")
        write_glb(
            coarse, export_dir / scene_dir.name / "model.glb", up=np.array([0, 0, 1.0]), centre=np.zeros(3)
        )
    t3 = time.perf_counter()
    gt = read_mesh_npz(scene_dir / "mesh_world.npz")
    test_masks = [v.mask for v in scene.test]
    scores = score_meshes({"hull": hull, "coarse": coarse}, gt, scene.test_cameras, test_masks, samples, seed)
    t4 = time.perf_counter()
    images = evaluate(g, scene)
    run = json.loads((cache / scene_dir.name / "coarse_run.json").read_text())
    return {
        **scores,
        "coarse_images": {
            k: images[k] for k in ("psnr", "ssim", "lpips_star", "see_through_pct") if k in images
        },
        "mesh_info": {k: v for k, v in info.items() if k != "settings"},
        "seconds": {
            "coarse_mesh": round(t1 - t0, 2),
            "hull_mesh": round(t2 - t1, 2),
            "write_files": round(t3 - t2, 2),
            "mesh_step_total": round(t3 - t0, 2),
            "metrics_both_meshes": round(t4 - t3, 2),
        },
        "coarse_model": {k: run[k] for k in ("gaussians", "coarse_cpu_s", "coarse_wall_s") if k in run},
    }


def previous_scenes(out: Path, protocol: dict) -> dict:
    """The scenes already in ``out`` when it was made with the same ``protocol`` (resumable runs)."""
    if not out.is_file():
        return {}
    old = json.loads(out.read_text())
    if any(old.get(k) != v for k, v in protocol.items()):
        raise SystemExit(f"{out}: made with another protocol, cannot --merge into it")
    return old["scenes"]


def summary(scenes: dict) -> dict:
    """Per mesh the mean of KEYS, and the issue's checks per scene."""
    means = {
        m: {k: float(np.mean([s[m][k] for s in scenes.values()])) for k in KEYS} for m in ("hull", "coarse")
    }
    checks = {
        name: {
            "chamfer_ratio_vs_hull": s["coarse"]["chamfer_l1"] / s["hull"]["chamfer_l1"],
            "chamfer_at_most_half_hull": s["coarse"]["chamfer_l1"] <= 0.5 * s["hull"]["chamfer_l1"],
            "fscore_1pct_above_hull": s["coarse"]["fscore_1pct"] > s["hull"]["fscore_1pct"],
            "silhouette_iou_above_hull": s["coarse"]["silhouette_iou"] > s["hull"]["silhouette_iou"],
        }
        for name, s in scenes.items()
    }
    return {"means": means, "checks": checks}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DEV)
    ap.add_argument("--scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--stage", choices=("train", "measure", "all"), default="all")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/geometry_dev"))
    ap.add_argument("--iterations", type=int, default=None, help="coarse budget (default: pipeline.yaml's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--samples", type=int, default=300_000, help="points sampled on each surface")
    ap.add_argument("--export", type=Path, default=None, help="also write model_mesh.ply / model.glb here")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/geometry_dev.json"))
    ap.add_argument("--merge", action="store_true", help="keep --out's other scenes (same protocol)")
    ap.add_argument("--mesh", nargs="*", default=[], metavar="KEY=VALUE", help="mesh step params to change")
    ap.add_argument("--variant", default="", help="name of a training variant (its models: --cache/NAME)")
    ap.add_argument(
        "--coarse", nargs="*", default=[], metavar="KEY=VALUE", help="the variant's coarse params"
    )
    args = ap.parse_args()
    params = mesh_params(args.mesh)
    extra = parse_overrides(args.coarse)
    if extra and not args.variant:
        raise SystemExit(
            "--coarse changes training: name the variant (--variant NAME) so its models are kept apart"
        )
    cache = args.cache / args.variant if args.variant else args.cache
    if args.stage in ("train", "all"):
        for name in args.scenes:
            print(f"{name}: coarse model {train(args.data / name, cache, args.iterations, args.seed, extra)}")
    if args.stage == "train":
        return
    protocol = {
        "seed": args.seed,
        "samples_per_surface": args.samples,
        "mesh_params": {k: getattr(params, k) for k in MeshSettings.__dataclass_fields__},
        "variant": args.variant or "defaults",
        "coarse_overrides": extra,
    }
    scenes = previous_scenes(args.out, protocol) if args.merge else {}
    for name in args.scenes:
        scenes[name] = measure(args.data / name, cache, args.seed, args.samples, args.export, params)
        h, c = scenes[name]["hull"], scenes[name]["coarse"]
        print(
            f"{name:14s} chamfer hull {h['chamfer_l1']:.4f} coarse {c['chamfer_l1']:.4f}  "
            f"F@1% {h['fscore_1pct']:.3f} -> {c['fscore_1pct']:.3f}  IoU {h['silhouette_iou']:.3f} -> "
            f"{c['silhouette_iou']:.3f}  mesh step {scenes[name]['seconds']['mesh_step_total']:.1f}s",
            flush=True,
        )
    result = {
        "benchmark": "geometry_dev",
        "final_mesh": "coarse model (the repair chain is not run in this benchmark)",
        "machine": platform.machine(),
        "torch_threads": torch.get_num_threads(),
        **protocol,
        "mesh_overrides": args.mesh,
        "scenes": scenes,
        **summary(scenes),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2, sort_keys=True))
    print(json.dumps(result["means"], indent=2))


if __name__ == "__main__":
    main()
