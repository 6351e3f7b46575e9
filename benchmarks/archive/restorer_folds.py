"""The restorer choice's held-out folds, scored again on finished work dirs (issue 34): for each work dir, the
tune step's inputs and params are read from its tune artifact (the one whose tune.json has a ``choice``), and
every fold is tuned and scored as the tune step does now (``_prior_outputs``, ``_fold_score``): the tuned
restorer, the prior as shipped and the mean of both. The record is the one the tune step would write
(``choice_record``), so runs made before a score was added can say what the rule would choose.

    python benchmarks/archive/restorer_folds.py --work milk=W/milk basket=W/basket --out OUT.json \
        [--fold-steps N]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from types import SimpleNamespace

from _machine import code_version  # benchmarks/ is on sys.path as a script


def tune_artifact(work: Path) -> Path:
    """The tune artifact of ``work`` that made a restorer choice (the newest if several)."""
    found = [d for d in (work / "artifacts" / "tune").iterdir() if (d / "tune.json").is_file()]
    found = [d for d in found if json.loads((d / "tune.json").read_text()).get("choice")]
    if not found:
        raise SystemExit(f"{work}: no tune artifact with a restorer choice")
    return max(found, key=lambda d: json.loads((d / "manifest.json").read_text())["finished"])


def score(work: Path, fold_steps: int | None = None) -> dict:
    from go_pipeline.steps import _repair_models as rm
    from go_pipeline.steps.params import TuneParams
    from go_pipeline.steps.weights import compact_info

    from go_core.compact.choice import choice_record
    from go_core.repair.data import training_views

    tune_dir = tune_artifact(work)
    manifest = json.loads((tune_dir / "manifest.json").read_text())
    inputs = {k: work / "artifacts" / v["step"] / v["key"] for k, v in manifest["inputs"].items()}
    known = {f.name for f in dataclasses.fields(TuneParams)}
    given = {k: tuple(v) if isinstance(v, list) else v for k, v in manifest["params"].items() if k in known}
    params = TuneParams(**given)
    if fold_steps is not None:  # tune.choice_steps: each fold's tuning steps (at most compact_steps)
        params = dataclasses.replace(params, choice_steps=fold_steps)
    name = compact_info(inputs)["name"]
    _, views = training_views(inputs["scene"], inputs.get("mask"), inputs["coarse"])
    held = rm.held_out_pairs(inputs)
    ctx = SimpleNamespace(seed=int(manifest["seed"]))
    start = time.perf_counter()
    prior = rm._prior_outputs(inputs, params, views, held)
    folds = [rm._fold_score(ctx, inputs, params, name, views, v, held[v], prior[v]) for v in held]
    return {
        "tune_artifact": str(tune_dir),
        "recorded": json.loads((tune_dir / "tune.json").read_text())["choice"],
        "scored": choice_record(folds, name, params.prior_choice),
        "fold_steps": rm.fold_tune_settings(params).steps,
        "seconds": round(time.perf_counter() - start, 1),
    }


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", nargs="+", required=True, help="NAME=WORKDIR")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--fold-steps", type=int, default=None, help="tune.choice_steps (default: the run's)")
    args = ap.parse_args(argv)
    out = json.loads(args.out.read_text()) if args.out.is_file() else {"commands": [], "scenes": {}}
    out["commands"].append(
        f"python benchmarks/archive/restorer_folds.py {' '.join(argv)} (code {code_version()})"
    )
    for item in args.work:
        name, work = item.split("=", 1)
        out["scenes"][name] = score(Path(work), args.fold_steps)
        s = out["scenes"][name]["scored"]
        print(
            name,
            {k: s[k] for k in ("chosen", "consensus_restorer", "tuned_psnr", "prior_psnr", "blend_psnr")},
        )
        args.out.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
