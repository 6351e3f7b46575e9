"""Compare repair-prior validation runs with their records (issue 34: is a remade corpus the same corpus?).

Each ``NAME:RUN_DIR:RECORDED`` pairs a ``benchmarks/prior/train_repair_prior.py`` output folder (its
``train_log.json``) with the run ``RECORDED`` of ``benchmarks/results/repair_prior_train.json``. Per
validation set (novel views, and the training views where both have them) the JSON holds the means over the
objects both runs validated, recorded against here, the means over every object here, and the per-object
figures side by side; for a training run also its CPU seconds and last logged losses against the record's::

    python benchmarks/archive/prior_validation_compare.py --out OUT.json \\
        prior4:/work/prior/validate_go-repair-prior-4:go-repair-prior-4
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

RECORDS = Path(__file__).resolve().parents[1] / "results" / "repair_prior_train.json"
METRICS = ("psnr_in", "psnr_out", "lp_in", "lp_out", "iou_in", "iou_out")
VALIDATION_SETS = ("validation", "validation_train_views")


def compare_set(here: dict, recorded: dict) -> dict:
    """One validation set of a run against the record's: means over the common objects, per object."""
    po_here, po_rec = here["per_object"], recorded["per_object"]
    common = [k for k in po_rec if k in po_here]
    return {
        "objects_recorded": len(po_rec),
        "objects_here": len(po_here),
        "objects_common": len(common),
        "mean_over_common": {
            m: {
                "recorded": round(float(np.mean([po_rec[k][m] for k in common])), 4),
                "here": round(float(np.mean([po_here[k][m] for k in common])), 4),
            }
            for m in METRICS
        },
        "mean_over_all_here": here["mean_over_objects"],
        "per_object": {
            k: {
                "recorded": {m: po_rec[k][m] for m in METRICS} if k in po_rec else None,
                "here": {m: po_here[k][m] for m in METRICS},
            }
            for k in po_here
        },
    }


def compare_run(run_dir: Path, recorded: dict, recorded_name: str) -> dict:
    """A run's ``train_log.json`` against its record: every validation set both have, and the training."""
    here = json.loads((run_dir / "train_log.json").read_text())
    out = {"command": here["command"], "recorded_run": recorded_name, "recorded_command": recorded["command"]}
    for key in VALIDATION_SETS:
        if key in here and key in recorded:
            out[key] = compare_set(here[key], recorded[key])
    if here.get("resumed_from", 0) == 0 and here.get("loss_log"):  # it trained: CPU and the last losses
        out["cpu_s_total"] = {"here": here["cpu_s_total"], "recorded": recorded.get("cpu_s_total")}
        out["loss_log_last"] = {"here": here["loss_log"][-5:], "recorded": recorded["loss_log"][-5:]}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--note", default="", help="what the runs are (stored with them)")
    ap.add_argument("runs", nargs="+", metavar="NAME:RUN_DIR:RECORDED")
    args = ap.parse_args(argv)
    records = json.loads(RECORDS.read_text())["runs"]
    runs = {}
    for item in args.runs:
        name, run_dir, recorded = item.split(":", 2)
        if recorded not in records:
            raise SystemExit(f"{RECORDS}: no recorded run {recorded!r}")
        runs[name] = compare_run(Path(run_dir), records[recorded], recorded)
    args.out.write_text(json.dumps({"note": args.note, "runs": runs}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
