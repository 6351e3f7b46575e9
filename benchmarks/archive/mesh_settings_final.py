"""Mesh-step settings measured on the final models of the dev scenes (issue 35): each variant's mesh, and the
visual hull's, scored against the ground truth as eval scores them (go_core.metrics.geometry.score_meshes:
Chamfer-L1, F@1%/2%, normal consistency, test-view silhouette IoU).

The final models are the ``repair_dir`` Gaussians of one variant of a ``repair_dev.py`` JSON (the default
chain's, cached), so only the mesh step differs between variants and nothing is retrained. A variant is
``NAME=JSON`` of MeshSettings overrides (``{}``: the defaults at the code being run).

    python benchmarks/archive/mesh_settings_final.py --data ../shared/data/dev \\
        --models benchmarks/results/repair_dev_prior2_ablations.json --variant realesr \\
        --settings 'seen1={"seen_views": 1}' 'seen2={"seen_views": 2}' --scenes milk \\
        --out benchmarks/results/mesh_seen_views.json          # more scenes: --merge
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from _final_models import add_model_arguments, final_gaussians, load_final  # benchmarks/ on sys.path
from _machine import code_version, cpu_name
from go_pipeline.steps.params import MeshParams

from go_core.mesh.extract import mesh_from_gaussians
from go_core.mesh.hull_mesh import hull_mesh
from go_core.mesh.settings import MeshSettings
from go_core.metrics.geometry import score_meshes

KEYS = ("chamfer_l1", "accuracy", "completeness", "fscore_1pct", "fscore_2pct", "normal_consistency",
        "silhouette_iou")  # fmt: skip


def rounded(res: dict) -> dict:
    return {k: round(float(res[k]), 4) for k in KEYS} | {"faces": res["faces"]}


def measure(scene_dir: Path, gaussians: Path, variants: dict[str, dict], samples: int, seed: int) -> dict:
    """One scene: the hull mesh's scores and each variant's (scores, ratio to the hull's Chamfer, seconds)."""
    final = load_final(scene_dir, gaussians)
    cams, masks, scene = final.cameras, final.masks, final.scene
    meshes, seconds, infos = {"hull": hull_mesh(cams, masks, MeshParams().hull_resolution)}, {}, {}
    for name, overrides in variants.items():
        t0 = time.perf_counter()
        settings = MeshSettings(**overrides)
        meshes[name], info = mesh_from_gaussians(final.gaussians, cams, final.box, settings, masks)
        seconds[name] = round(time.perf_counter() - t0, 1)
        infos[name] = {"faces_unseen_dropped": info["faces_unseen_dropped"]}
    test_masks = [v.mask for v in scene.test]
    scores = score_meshes(meshes, final.truth, scene.test_cameras, test_masks, samples, seed)
    hull = rounded(scores["hull"])
    out = {"gaussians": str(gaussians), "hull": hull, "variants": {}}
    for name in variants:
        res = rounded(scores[name])
        res["chamfer_ratio_to_hull"] = round(res["chamfer_l1"] / hull["chamfer_l1"], 3)
        out["variants"][name] = res | infos[name] | {"mesh_seconds": seconds[name]}
    return out


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_model_arguments(ap, "realesr")
    ap.add_argument("--settings", nargs="+", required=True, help="NAME=JSON MeshSettings overrides")
    ap.add_argument("--scenes", nargs="+", required=True)
    ap.add_argument("--samples", type=int, default=300_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--merge", action="store_true", help="add the scenes to an existing --out")
    args = ap.parse_args(argv)
    variants = {}
    for item in args.settings:
        name, _, text = item.partition("=")
        variants[name] = json.loads(text)
        MeshSettings(**variants[name])  # an unknown or out-of-range setting stops here, before any work
    models = final_gaussians(args.models, args.variant)
    result = json.loads(args.out.read_text()) if args.merge else {
        "settings": {"samples": args.samples, "seed": args.seed, "variants": variants,
                     "models": f"{args.models} ({args.variant})"},
        "machine": cpu_name(), "threads": torch.get_num_threads(),
        "commands": [], "scenes": {}}  # fmt: skip
    command = f"python benchmarks/archive/mesh_settings_final.py {' '.join(argv)}"
    result["commands"].append(f"{command} (code {code_version()})")
    for name in args.scenes:
        result["scenes"][name] = measure(args.data / name, models[name], variants, args.samples, args.seed)
        print(name, json.dumps(result["scenes"][name]), flush=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
