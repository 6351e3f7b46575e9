"""Merge several ``repair_dev.py`` JSONs (one per object, run side by side) into one results file: every
object's record, every command, and a summary of the variants per object and over all of them (PSNR /
SSIM / LPIPS*, the restorer the folds chose, the fold PSNRs). ``--previous`` names an earlier merged file
whose per-object figures the summary sets beside today's (the same objects at another code).

    python benchmarks/merge_repair_dev.py --out benchmarks/results/repair_val_objects_1206.json \\
        --note "..." --previous benchmarks/results/repair_val_objects.json W/val_*.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

METRICS = ("psnr", "ssim", "lpips_star")


def object_name(scene: str) -> str:
    """The corpus object of a scene folder: ``pybullet_objects__blob_000`` → ``pybullet_objects/blob_000``."""
    return scene.replace("__", "/", 1)


def object_summary(record: dict) -> dict:
    """One object's variants (metrics rounded to 4 places), the restorers its folds chose and their PSNRs."""
    lora = record.get("lora") or {}
    out = {
        name: {k: round(float(v[k]), 4) for k in METRICS}
        for name, v in record["variants"].items()
        if all(v.get(k) is not None for k in METRICS)
    }
    out["restorer_chosen"] = lora.get("restorer_chosen", "")
    out["second_model_restorer"] = lora.get("consensus_restorer") or "own"
    out["fold_psnr"] = {k: lora[k] for k in ("tuned_psnr", "prior_psnr", "blend_psnr") if k in lora}
    if "loo_pair_psnr" in record:
        out["loo_pair_psnr"] = round(float(record["loo_pair_psnr"]), 4)
    return out


def means(per_object: dict, variants: list[str]) -> dict:
    """Per variant present on every object: the mean of each metric."""
    out = {}
    for variant in variants:
        rows = [o[variant] for o in per_object.values() if variant in o]
        if len(rows) == len(per_object):
            out[variant] = {k: round(sum(r[k] for r in rows) / len(rows), 4) for k in METRICS}
    return out


def merge(paths: list[Path], previous: Path | None) -> dict:
    """The merged record of ``paths`` (an object twice is an error: which run would count?)."""
    objects, commands, variants = {}, [], []
    runs = [(path, json.loads(path.read_text())) for path in paths]
    for path, data in runs:
        commands += data.get("commands", [data.get("command", "")])
        for scene, record in data["scenes"].items():
            name = object_name(scene)
            if name in objects:
                raise SystemExit(f"merge_repair_dev: {path}: {name} is already in another file")
            objects[name] = record
            variants += [v for v in record["variants"] if v not in variants]
    per_object = {name: object_summary(r) for name, r in sorted(objects.items())}
    summary = {"objects_compared": len(per_object), "means": means(per_object, variants)}
    summary["per_object"] = per_object
    if previous is not None:
        old = json.loads(previous.read_text())["summary"]["per_object"]
        summary["previous"] = {
            "file": str(previous),
            "per_object": {n: {v: old[n][v] for v in variants if v in old.get(n, {})} for n in per_object},
        }
    keep = ("cpu", "cpu_count", "machine", "threads", "torch", "seed", "overrides")
    machine = {k: runs[0][1].get(k) for k in keep}
    return machine | {"commands": commands, "objects": objects, "summary": summary}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("inputs", nargs="+", type=Path, help="repair_dev.py JSONs")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--note", default="", help="what was run, where and how (kept in the file)")
    ap.add_argument("--previous", type=Path, help="an earlier merged file of the same objects")
    args = ap.parse_args()
    merged = {"note": args.note} | merge(args.inputs, args.previous)
    args.out.write_text(json.dumps(merged, indent=1) + "\n")
    for variant, m in merged["summary"]["means"].items():
        print(f"{variant:10s} " + " / ".join(f"{m[k]:.2f}" for k in METRICS))


if __name__ == "__main__":
    main()
