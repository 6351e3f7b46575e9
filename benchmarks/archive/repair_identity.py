"""The repair chain with an identity restorer: what is left of the repair's gain when no restorer changes the
views it repairs (issue 34: how much of the gain is the restorer's).

The identity is an untrained repair prior (`go_core.compact.prior.RepairPrior`, whose zero-initialised head
makes its output its input, RGB and alpha alike; tested in tests/test_repair_prior.py), installed for this
process only as a shipped prior named ``identity-prior``. It repairs both models of the consensus without
tuning (``tune.finetune`` false, ``tune.prior_choice`` ''), and its alpha is no mask target
(``repair.alpha_weight`` 0): every repaired view is the two models' agreed render, so the repair step
distils the agreement and keeps training on the photos, and nothing else changes. The steps before the
weights step are those of the work dir given (cached from an earlier ``benchmarks/repair_dev.py`` run),
so the comparison with that run's ``full`` and ``no_repair`` variants is on the same coarse model.

    python benchmarks/archive/repair_identity.py --out OUT.json SCENE_DIR:WORK_DIR:SEED ...

where WORK_DIR is ``repair_dev.py``'s ``--workroot``/<scene>. Runs in this process (the installed prior is
not seen by a worker process), on the threads torch is given (OMP_NUM_THREADS).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

from _machine import torch_run_context  # benchmarks/ is on sys.path as a script

IDENTITY = "identity-prior"
OVERRIDES = {
    "weights.compact_model": IDENTITY,
    "tune.finetune": False,
    "tune.prior_choice": "",
    "repair.alpha_weight": 0.0,
}


def install_identity_prior(folder: Path) -> str:
    """Write the identity prior into ``folder`` and make it this process's only extra shipped prior; returns
    its SHA-256."""
    from go_core.compact import prior
    from go_core.seeding import seeded_torch_init

    with seeded_torch_init(0, "identity_prior"):
        model = prior.RepairPrior(prior.PriorConfig())
    path = prior.save_prior(folder / f"{IDENTITY}.safetensors", model)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    for name in prior.SHIPPED:  # the shipped priors stay loadable from the new folder
        target = folder / f"{name}.safetensors"
        if not target.exists():
            target.symlink_to(prior.SHIPPED_DIR / target.name)
    prior.SHIPPED_DIR = folder
    prior.SHIPPED = {**prior.SHIPPED, IDENTITY: digest}
    return digest


def run_one(scene: Path, workdir: Path, seed: int) -> dict:
    """The pipeline at OVERRIDES on ``workdir``: the eval's means, the final mesh's Chamfer-L1 and the test
    views' PSNR."""
    from go_pipeline.runner import run_pipeline

    t0 = time.perf_counter()
    summary = run_pipeline(
        scene, workdir=workdir, overrides=OVERRIDES, seed=seed, quiet=True, in_process=True
    )
    metrics = json.loads((summary.step("eval").artifact_dir / "metrics.json").read_text())
    final = (metrics.get("geometry") or {}).get("final") or {}
    return {
        "psnr": metrics["mean"]["psnr"],
        "ssim": metrics["mean"]["ssim"],
        "lpips_star": metrics["mean"]["lpips_star"],
        "chamfer_l1": final.get("chamfer_l1"),
        "model": metrics["model"],
        "run_wall_s": round(time.perf_counter() - t0, 1),
        "view_psnr": [v["psnr"] for v in metrics["views"]],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", help="SCENE_DIR:WORK_DIR:SEED")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument(
        "--priors", type=Path, default=None, help="folder for the identity prior (default: beside --out)"
    )
    args = ap.parse_args()

    folder = args.priors or args.out.parent / "identity_prior"
    folder.mkdir(parents=True, exist_ok=True)
    digest = install_identity_prior(folder)
    result = json.loads(args.out.read_text()) if args.out.exists() else {"runs": {}, "commands": []}
    where = torch_run_context()
    result["commands"].append(
        f"python benchmarks/archive/repair_identity.py {' '.join(sys.argv[1:])} ({where})"
    )
    result["overrides"], result["identity_sha256"] = OVERRIDES, digest
    for spec in args.runs:
        scene, work, seed = spec.rsplit(":", 2)
        key = f"{Path(work).name}:{seed}"
        result["runs"][key] = run_one(Path(scene), Path(work), int(seed))
        args.out.write_text(json.dumps(result, indent=1))
        print(key, result["runs"][key]["psnr"], result["runs"][key]["lpips_star"], flush=True)


if __name__ == "__main__":
    main()
