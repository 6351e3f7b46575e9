"""The repair chain on the dev scenes: full pipeline vs its own coarse model, with the paper's ablations.

Per scene, one work dir and the real runner (`run_pipeline`, cached steps shared between the variants):
  full        default settings (weights.repair_model auto → the compact model here): coarse → loo →
              noise_pairs → tune (per-scene tuning) → repair → eval
  pretrained  ablation "pretrained only, no tuning": --set tune.finetune=false
  no_repair   ablation "no repair": --set repair.mode=no_repair (eval scores the coarse model)
  realesr     the compact restorer realesr-animevideov3-x4, tuned (the default before the repair prior)
  prior       the repair prior trained on the corpus (issue 34), tuned, with its alpha as a mask target
              (repair.alpha_weight=1); prior_pretrained: not tuned; prior_no_alpha: alpha_weight 0;
              prior_no_reference: the prior trained without the reference input (go-repair-prior-1-noref)
  prior2      go-repair-prior-2 (go-repair-prior-1 trained on to 8000 steps), tuned, alpha_weight 0 (the
              default until 2026-12-05, kept in these variants as measured); prior2_pretrained: not
              tuned; prior2_tune60: tuned for 60 steps instead of 400;
              prior2_pretrained_alpha: not tuned, its alpha as a mask target; noref_pretrained:
              go-repair-prior-1-noref not tuned; prior3_pretrained: go-repair-prior-3, not tuned;
              prior4_pretrained: go-repair-prior-4, not tuned (prior4_pretrained_alpha: with its alpha as
              a mask target); prior4: tuned; prior4_inside: tuned with
              the RGB loss inside the training masks only (tune.compact_region inside);
              prior4_noref_pretrained: go-repair-prior-4-noref (prior-4's chain without the reference
              input), not tuned (prior4_noref_pretrained_alpha: with its alpha as a mask target, i.e. the
              `prior` profile without the reference input)
  no_reference  ablation "without the reference input": the defaults with go-repair-prior-4-noref as
              tune.prior_choice in place of go-repair-prior-4
  no_alpha_target  ablation "without the alpha target": repair.alpha_weight=0, so a repair prior's alpha is
              no mask target where it repairs either model (elsewhere the same bytes as full)
  no_prior    issue 34's comparator: the defaults without a repair prior (tune.prior_choice ''), the tuned
              realesr repairs both models; the JSON's ``against_no_prior`` sets every variant against it
  lift30      every repaired view with a twin raised 30 degrees (repair.lift_deg 30)
  repair_x075, repair_x050  the repair's schedule compressed to 3/4 and 1/2 of its length (every iteration
              count of it scaled alike: repair_schedule), for the speed-against-error trade
Test-view PSNR / SSIM / LPIPS* (VGG, x100) from each variant's eval metrics.json, with where the error is
(``error_split``: outside the true silhouette, on surface a training view sees, on surface none sees; issue
34 item 4), the final mesh's geometry against the ground truth (``geometry``, issue 35), the tune step's
restorer choice on its held-out folds (``tune_choice``), plus the wall
and CPU seconds of every step from its manifest (the step's original run, also when cached here), per
variant and, from the defaults' run, per scene. Writes a
JSON and one contact sheet per scene (rows: truth / coarse / the repaired models of SHEET_ROWS that ran, for
``--sheet-views`` test views).

    nice -n 10 python benchmarks/repair_dev.py --scenes milk basket --workroot /tmp/repair_dev \
        --out benchmarks/results/repair_dev.json --sheets docs/img

``merge`` joins several of its JSONs (one per object, run side by side) into one results file: every object's
record, every command, and a summary of the variants per object and over all of them (PSNR / SSIM / LPIPS*,
the restorer the folds chose, the fold PSNRs); ``--previous`` names an earlier merged file whose per-object
figures the summary sets beside today's (the same objects at another code):

    python benchmarks/repair_dev.py merge --out benchmarks/results/repair_val_objects_1206.json \
        --note "..." --previous benchmarks/results/repair_val_objects.json W/val_*.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
from _lib.machine import code_version, cpu_name  # benchmarks/ is on sys.path as a script

from go_pipeline.store import read_manifest

DEV = Path(__file__).resolve().parents[2] / "shared" / "data" / "dev"
PRIOR = "go-repair-prior-1"  # the repair prior trained on the corpus (issue 34, docs/repair_prior.md)
PRIOR2 = "go-repair-prior-2"  # the same prior trained on, to 8000 steps (cosine learning rate)
PRIOR3 = "go-repair-prior-3"  # prior-2 fine-tuned with the object's pixels weighted up (--inside-weight)
PRIOR4 = "go-repair-prior-4"  # prior-3 fine-tuned with pairs at the training views (--train-view-share)
PRIOR4_NOREF = "go-repair-prior-4-noref"  # prior-4's training chain without the reference input
NO_ALPHA = {"repair.alpha_weight": 0.0}  # as the variants below were measured: the default until 2026-12-05
# the repair's iteration counts that set its schedule: scaled together by repair_schedule
SCHEDULE = (
    "iterations",
    "repair_iterations",
    "refresh_every",
    "densify_from",
    "densify_until",
    "densify_every",
)


def repair_schedule(fraction: float) -> dict[str, int]:
    """--set overrides that compress the repair's default schedule to ``fraction`` of its length: every
    iteration count scaled alike, so the repair makes as many refreshes and densifications, each over
    fewer iterations (the same for the consensus's second model, which runs the same settings)."""
    from go_core.repair.settings import RepairSettings

    defaults = RepairSettings()
    return {f"repair.{name}": max(1, round(getattr(defaults, name) * fraction)) for name in SCHEDULE}


VARIANTS = {
    "full": {},
    "pretrained": {"tune.finetune": False},
    "no_repair": {"repair.mode": "no_repair"},
    "realesr": {"weights.compact_model": "realesr-animevideov3-x4"},  # the restorer before the prior
    "prior": {"weights.compact_model": PRIOR, "repair.alpha_weight": 1.0},  # as measured: the alpha target on
    "prior_pretrained": {"weights.compact_model": PRIOR, "tune.finetune": False, "repair.alpha_weight": 1.0},
    "prior_no_alpha": {"weights.compact_model": PRIOR, "repair.alpha_weight": 0.0},
    "prior_no_reference": {"weights.compact_model": PRIOR + "-noref", "repair.alpha_weight": 1.0},
    "prior2": {"weights.compact_model": PRIOR2, **NO_ALPHA},  # tuned, as measured (weight 0)
    "prior2_pretrained": {"weights.compact_model": PRIOR2, "tune.finetune": False, **NO_ALPHA},
    "prior2_tune60": {"weights.compact_model": PRIOR2, "tune.compact_steps": 60, **NO_ALPHA},  # short tuning
    "prior2_pretrained_alpha": {
        "weights.compact_model": PRIOR2,
        "tune.finetune": False,
        "repair.alpha_weight": 1.0,
    },
    "noref_pretrained": {"weights.compact_model": PRIOR + "-noref", "tune.finetune": False, **NO_ALPHA},
    "prior3_pretrained": {"weights.compact_model": PRIOR3, "tune.finetune": False, **NO_ALPHA},
    "prior4_pretrained": {"weights.compact_model": PRIOR4, "tune.finetune": False, **NO_ALPHA},
    "prior4_pretrained_alpha": {  # the same, with its predicted alpha as a mask target
        "weights.compact_model": PRIOR4,
        "tune.finetune": False,
        "repair.alpha_weight": 1.0,
    },
    "prior4": {"weights.compact_model": PRIOR4, **NO_ALPHA},  # tuned 400 steps, the RGB loss over the view
    "prior4_inside": {"weights.compact_model": PRIOR4, "tune.compact_region": "inside", **NO_ALPHA},
    "prior4_noref_pretrained": {"weights.compact_model": PRIOR4_NOREF, "tune.finetune": False, **NO_ALPHA},
    "prior4_noref_pretrained_alpha": {  # the `prior` profile without the reference input
        "weights.compact_model": PRIOR4_NOREF,
        "tune.finetune": False,
        "repair.alpha_weight": 1.0,
    },
    "no_reference": {"tune.prior_choice": PRIOR4_NOREF},  # issue 34's ablation "without the reference input"
    # the ablation without the alpha target: a repair prior's alpha is no mask target (the default before
    # 2026-12-05); scenes where no prior repairs either model are the same bytes as 'full'
    "no_alpha_target": NO_ALPHA,
    # every repaired view with a twin raised 30 degrees (docs/repair.md, 'Raised views on plate')
    "lift30": {"repair.lift_deg": 30.0},
    # issue 34's comparator: the tuned realesr repairs both models, never a repair prior
    "no_prior": {"tune.prior_choice": ""},
    # the repair's schedule compressed to three quarters and a half of its length (speed against error)
    "repair_x075": repair_schedule(0.75),
    "repair_x050": repair_schedule(0.5),
}
# contact-sheet rows after truth and coarse, when they ran
SHEET_ROWS = ("realesr", "full", "prior", "prior2_pretrained")
# the tune record's restorer choice on the held-out folds (go_core/compact/choice.py), kept per variant
CHOICE_KEYS = ("restorer_chosen", "consensus_restorer", "prior_psnr", "tuned_psnr", "blend_psnr")
STEPS = ("scene", "mask", "hull", "coarse", "weights", "loo", "noise_pairs", "tune", "repair", "eval")


def loo_pair_psnr(loo_dir: Path) -> float:
    """Mean PSNR of the leave-one-out renders against their left-out photo (on white): how degraded the
    tuning pairs are, to compare with the coarse model's own test-view PSNR."""
    with np.load(Path(loo_dir) / "loo_pairs.npz") as data:
        arrays = {k: data[k].astype(np.float64) / 255.0 for k in data.files}
    pairs = json.loads((Path(loo_dir) / "loo.json").read_text())["pairs"]
    mse = [np.mean((arrays[p["degraded"]][..., :3] - arrays[p["clean"]]) ** 2) for p in pairs]  # RGB of RGBA
    return float(np.mean([-10.0 * np.log10(max(m, 1e-12)) for m in mse]))


def _geometry(geometry: dict | None) -> dict | None:
    """The final mesh's and the visual hull's scores from eval's ``geometry`` (None without a mesh)."""
    if not geometry or geometry.get("status") != "ok":
        return None
    keys = ("chamfer_l1", "fscore_1pct", "fscore_2pct", "normal_consistency", "silhouette_iou")
    return {mesh: {k: geometry[mesh][k] for k in keys} for mesh in ("final", "hull")}


def _sheet(scene_dir: Path, repaired: list[Path], out: Path, views: int, workdir: Path) -> None:
    """Rows truth / coarse / one per repaired model (``repaired``: repair artifact dirs, in order) for
    ``views`` test views (renders made again, white background)."""
    import torch
    from PIL import Image

    from go_core.gaussians import Gaussians
    from go_core.metrics.evaluate import composite
    from go_core.repair.data import render_rgb_alpha, to_uint8
    from go_core.scene.artifact import load_scene_artifact

    del scene_dir
    arts = workdir / "artifacts"

    def newest(step: str) -> Path:
        return max((d for d in (arts / step).iterdir() if d.is_dir()), key=lambda d: d.stat().st_mtime)

    scene = load_scene_artifact(newest("scene"))
    models = [Gaussians.load(newest("coarse") / "gaussians.npz")]
    models += [Gaussians.load(d / "gaussians.npz") for d in repaired]
    idx = np.linspace(0, len(scene.test) - 1, views).round().astype(int)
    rows = [[] for _ in range(1 + len(models))]
    with torch.no_grad():
        for i in idx:
            v, cam = scene.test[i], scene.test_cameras[i]
            rows[0].append(to_uint8(composite(v.image, v.mask)))
            for row, model in zip(rows[1:], models, strict=True):
                row.append(to_uint8(render_rgb_alpha(model, cam, 1.0)[0]))
    sheet = np.concatenate([np.concatenate(r, axis=1) for r in rows], axis=0)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(sheet).save(out, format="JPEG", quality=88)


def _against(base: str, scenes: dict) -> dict:
    """Each variant against ``base`` on the scenes that ran both: per-scene PSNR and LPIPS* changes, the
    mean PSNR change and whether LPIPS* is lower on every scene (issue 34's check, prior vs realesr)."""
    out = {}
    names = {v for s in scenes.values() for v in s["variants"]} - {base}
    for variant in sorted(names):
        both = {
            n: s["variants"] for n, s in scenes.items() if base in s["variants"] and variant in s["variants"]
        }
        if not both:
            continue
        per = {
            n: {
                "psnr_change": round(v[variant]["psnr"] - v[base]["psnr"], 3),
                "lpips_star_change": round(v[variant]["lpips_star"] - v[base]["lpips_star"], 3),
            }
            for n, v in both.items()
        }
        out[variant] = {
            "scenes": per,
            "mean_psnr_change": round(float(np.mean([d["psnr_change"] for d in per.values()])), 3),
            "lpips_lower_on_every_scene": all(d["lpips_star_change"] < 0 for d in per.values()),
        }
    return out


def _parse_args(argv: list[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], epilog="merge: see merge --help")
    ap.add_argument("--scenes", nargs="+", default=["milk", "alphabet_soup", "basket", "plate", "white_bowl"])
    ap.add_argument("--data", type=Path, default=DEV)
    ap.add_argument("--workroot", type=Path, required=True)
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="STEP.PARAM=VALUE for all")
    ap.add_argument("--variants", nargs="+", default=["full", "pretrained", "no_repair"], choices=VARIANTS)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--sheets", type=Path, default=None, help="folder for <scene>_repair_sheet.jpg")
    ap.add_argument("--sheet-views", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0, help="the runs' seed (one per --out file)")
    return ap.parse_args(argv)


def _new_result(args: argparse.Namespace, common: dict) -> dict:
    """The JSON's header; where ``--out`` exists, its scenes and commands are kept (a resumed or extended
    run), and this invocation's command is appended with its code and machine."""
    import torch

    command = "python benchmarks/repair_dev.py " + " ".join(os.sys.argv[1:])
    result: dict = {
        "command": command,
        "commands": [],  # every invocation that wrote this file, in order, with its code and machine
        "machine": platform.processor() or platform.machine(),
        "cpu": cpu_name(),
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "cpu_count": os.cpu_count(),
        "load_average_start": os.getloadavg(),
        "overrides": common,
        "seed": args.seed,
        "scenes": {},
    }
    if args.out.exists():  # resume: keep scenes measured by an earlier invocation, and its command
        earlier = json.loads(args.out.read_text())
        if earlier.get("seed", 0) != args.seed:
            raise SystemExit(f"{args.out}: its runs are at seed {earlier.get('seed', 0)}, not {args.seed}")
        result["scenes"] = earlier.get("scenes", {})
        result["commands"] = earlier.get("commands") or ([earlier["command"]] if "command" in earlier else [])
    result["commands"].append(f"{command} (code {code_version()}, {result['cpu']}, torch {result['torch']})")
    return result


def _step_times(summary) -> dict:
    """Every step's wall and CPU seconds from its manifest (its original run, also when cached here)."""
    times = {}
    for step in STEPS:
        m = read_manifest(summary.step(step).artifact_dir) or {}
        times[step] = {"wall_s": m.get("wall_s"), "cpu_s": m.get("cpu_s")}
    return times


def _variant_record(summary, wall_s: float) -> dict:
    """One variant's figures from its eval step, with where its repair and eval artifacts are, its tune
    step's restorer choice and every step's time."""
    eval_dir = summary.step("eval").artifact_dir
    metrics = json.loads((eval_dir / "metrics.json").read_text())
    mean = metrics["mean"]
    repair_dir = summary.step("repair").artifact_dir
    tune_record = summary.step("tune").record or {}
    return {
        "psnr": mean["psnr"],
        "ssim": mean["ssim"],
        "lpips_star": mean["lpips_star"],
        "model": metrics["model"],
        "repair_model": metrics.get("repair_model", ""),
        "run_wall_s": round(wall_s, 1),
        "eval_dir": str(eval_dir),
        "repair_dir": str(repair_dir) if (repair_dir / "gaussians.npz").exists() else None,
        "error_split": (metrics.get("error_split") or {}).get("regions"),
        "geometry": _geometry(metrics.get("geometry")),
        "tune_choice": {k: tune_record.get(k) for k in CHOICE_KEYS},
        "steps": _step_times(summary),
    }


def _record_full_run(entry: dict, summary) -> None:
    """What only the defaults' run records: every step's wall and CPU (as the scene's), the tune and repair
    records and the leave-one-out pairs' PSNR."""
    entry["steps"] = _step_times(summary)
    entry["lora"] = summary.step("tune").record
    entry["loo_pair_psnr"] = loo_pair_psnr(summary.step("loo").artifact_dir)
    entry["repair"] = {k: v for k, v in summary.step("repair").record.items() if k != "l_rep_last"}


def _summarise(result: dict) -> None:
    """The full pipeline against its coarse model over the scenes that ran both, and every variant against
    the tuned realesr and against the defaults without a repair prior (issue 34's comparators)."""
    done = [s for s in result["scenes"].values() if "lpips_star_gain" in s]
    if done:
        result["summary"] = {
            "scenes": len(done),
            "lpips_lower_on_every_scene": all(s["lpips_star_gain"] > 0 for s in done),
            "mean_psnr_change": float(np.mean([s["psnr_change"] for s in done])),
            "mean_lpips_star_gain": float(np.mean([s["lpips_star_gain"] for s in done])),
        }
    result["against_realesr"] = _against("realesr", result["scenes"])
    result["against_no_prior"] = _against("no_prior", result["scenes"])


# ``merge``: per-object JSONs of this script, run side by side, joined into one results file
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
                raise SystemExit(f"repair_dev.py merge: {path}: {name} is already in another file")
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


def merge_main(argv: list[str]) -> None:
    """``repair_dev.py merge``: write the merged file and print each variant's means."""
    ap = argparse.ArgumentParser(
        prog="repair_dev.py merge", description="Merge per-object repair_dev.py JSONs into one results file."
    )
    ap.add_argument("inputs", nargs="+", type=Path, help="repair_dev.py JSONs")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--note", default="", help="what was run, where and how (kept in the file)")
    ap.add_argument("--previous", type=Path, help="an earlier merged file of the same objects")
    args = ap.parse_args(argv)
    merged = {"note": args.note} | merge(args.inputs, args.previous)
    args.out.write_text(json.dumps(merged, indent=1) + "\n")
    for variant, m in merged["summary"]["means"].items():
        print(f"{variant:10s} " + " / ".join(f"{m[k]:.2f}" for k in METRICS))


def run(args: argparse.Namespace) -> None:
    """Every variant on every scene, the JSON rewritten after each scene, then the summary."""
    from go_pipeline.pipeline import parse_set_argument
    from go_pipeline.runner import run_pipeline

    common = dict(parse_set_argument(item) for item in args.overrides)
    result = _new_result(args, common)
    for name in args.scenes:
        scene_dir = args.data / name
        workdir = args.workroot / name
        entry: dict = result["scenes"].get(name) or {"variants": {}, "steps": {}}  # variants add up
        for variant in args.variants:
            t0 = time.perf_counter()
            overrides = {**common, **VARIANTS[variant]}
            summary = run_pipeline(
                scene_dir, workdir=workdir, overrides=overrides, seed=args.seed, quiet=True
            )
            entry["variants"][variant] = _variant_record(summary, time.perf_counter() - t0)
            if variant == "full":
                _record_full_run(entry, summary)
            figures = {k: entry["variants"][variant][k] for k in ("psnr", "ssim", "lpips_star")}
            print(name, variant, figures, flush=True)
        v = entry["variants"]
        if "full" in v and "no_repair" in v:
            entry["lpips_star_gain"] = v["no_repair"]["lpips_star"] - v["full"]["lpips_star"]
            entry["psnr_change"] = v["full"]["psnr"] - v["no_repair"]["psnr"]
        repaired = [Path(v[k]["repair_dir"]) for k in SHEET_ROWS if k in v and v[k].get("repair_dir")]
        if args.sheets is not None and repaired:
            _sheet(scene_dir, list(dict.fromkeys(repaired)), args.sheets / f"{name}_repair_sheet.jpg",
                   args.sheet_views, workdir)  # fmt: skip
        result["scenes"][name] = entry
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
    _summarise(result)
    result["load_average_end"] = os.getloadavg()
    args.out.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["merge"]:
        merge_main(argv[1:])
    else:
        run(_parse_args(argv))


if __name__ == "__main__":
    main()
