"""Does a held-out fold of a scene's own tuning pairs say whether tuning the repair prior helps it (issue 34)?

Per dev scene (its cached run in ``--workroot``, the tune step of the prior's tuned variant) and per training
view k: the prior is tuned as the tune step tunes it (TuneParams defaults: 400 steps) on every pair whose
view is not k (noise pairs and leave-one-out pairs), and its loss on view k's leave-one-out pairs (never
drawn) is measured before and after. Prints one line per fold and a RESULT line per scene:

    python benchmarks/archive/tune_heldout_folds.py --workroot W --prior go-repair-prior-4 \\
        --scenes alphabet_soup milk white_bowl
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from go_pipeline.steps._repair_models import _pair_source, compact_tune_settings
from go_pipeline.steps.params import TuneParams

from go_core.compact.restorer import load_restorer
from go_core.compact.tuning import held_out_loss, tune_compact
from go_core.repair.data import training_views
from go_core.repair.pairs import LooPairs, pair_tensors, training_view_references, with_reference


def tune_inputs(workdir: Path, prior: str) -> dict[str, Path]:
    """The input artifact folders of the last tune step that fine-tuned ``prior`` over the whole view."""
    found = None
    for d in sorted((workdir / "artifacts" / "tune").iterdir()):
        t = json.loads((d / "tune.json").read_text())
        if t.get("status") == "ok" and t["compact"]["name"] == prior and t["settings"]["region"] == "all":
            found = d
    if found is None:
        raise SystemExit(f"error: {workdir}: no tune step of {prior} to take the inputs from")
    inputs = json.loads((found / "manifest.json").read_text())["inputs"]
    return {k: workdir / "artifacts" / v["step"] / v["key"] for k, v in inputs.items()}


def fold(inputs: dict[str, Path], prior: str, k: int, settings, params, views, loo) -> tuple[float, float]:
    """(loss before, loss after) on view ``k``'s leave-one-out pairs, tuned on every other view's pairs."""
    source = _pair_source(inputs, params, views)
    refs = training_view_references(views, source.coarse, params.backend)
    model = load_restorer(prior)
    held = [
        pair_tensors(with_reference(loo.get(i), refs), settings.resolution, model.channels)
        for i in range(len(loo))
        if loo.get(i).view == k
    ]

    def draw(rng, gen):
        while True:
            pair = source.draw(rng, gen)
            if pair.view != k:
                return with_reference(pair, refs)

    before = held_out_loss(model, held)
    tune_compact(model, draw, source.schedule, settings, 0)
    return before, held_out_loss(model, held)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workroot", type=Path, required=True, help="repair_dev.py --workroot")
    ap.add_argument("--prior", default="go-repair-prior-4")
    ap.add_argument("--scenes", nargs="+", required=True)
    args = ap.parse_args(argv)
    params = TuneParams()
    settings = compact_tune_settings(params)  # no checkpoint folder: its checkpoint_every is unused
    for scene in args.scenes:
        inputs = tune_inputs(args.workroot / scene, args.prior)
        _, views = training_views(inputs["scene"], inputs.get("mask"), inputs["coarse"])
        loo, res = LooPairs(inputs["loo"]), []
        for k in range(len(views)):
            t0 = time.time()
            res.append(fold(inputs, args.prior, k, settings, params, views, loo))
            print(scene, k, *(round(x, 6) for x in res[-1]), round(time.time() - t0, 1), flush=True)
        before, after = np.array(res).T
        rel = float(np.mean(after / before - 1))
        out = {"before": before.tolist(), "after": after.tolist(), "mean_rel": rel}
        print("RESULT", scene, json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
