"""tune.prior_choice: the tuned restorer against a repair prior as shipped, on held-out leave-one-out
folds."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from go_core.compact.choice import (
    FoldScore,
    blend_psnr,
    choice_record,
    choose_blend,
    choose_prior,
    mean_psnr,
    psnr,
    restored,
)
from tests import test_compact
from tests.test_compact import LORA, REPAIR, _repair, _tune

# the compact tests' fixtures: the tiny upstream steps, the tiny restorer cache and the tiny shipped prior
upstream, tiny_cache, tiny_prior = test_compact.upstream, test_compact.tiny_cache, test_compact.tiny_prior

CHOICE = {**LORA, "prior_choice": "tiny-prior"}
TUNED = "realesr-animevideov3-x4"  # the tiny stand-in of tests/_tiny_repair.py


def restored_psnr(model: torch.nn.Module, pairs) -> float:
    """The mean PSNR a fold scores a restorer by: its outputs (``restored``) against the clean RGB."""
    return mean_psnr(restored(model, pairs), pairs)


class _Shift(torch.nn.Module):
    """Adds a constant to its input (a stand-in restorer with a known error)."""

    def __init__(self, shift: float) -> None:
        super().__init__()
        self.shift = shift

    def forward(self, x):
        return x + self.shift


def test_restored_psnr_against_hand_values():
    clean = torch.full((1, 3, 8, 8), 0.5)
    degraded = torch.cat([clean - 0.1, torch.ones(1, 1, 8, 8)], 1)  # a prior's alpha channel is left out
    assert restored_psnr(_Shift(0.0), [(degraded, clean)]) == pytest.approx(20.0, abs=1e-4)  # MSE 0.01
    assert restored_psnr(_Shift(0.1), [(degraded, clean)]) == pytest.approx(120.0)  # exact: floored at 1e-12
    over = torch.cat([torch.full((1, 3, 8, 8), 0.95), torch.ones(1, 1, 8, 8)], 1)
    assert restored_psnr(_Shift(0.2), [(over, torch.ones(1, 3, 8, 8))]) == pytest.approx(
        120.0
    )  # clamped at 1
    assert psnr(torch.zeros(4), torch.full((4,), 0.5)) == pytest.approx(-10 * np.log10(0.25))
    with pytest.raises(ValueError, match="no held-out pairs"):
        restored_psnr(_Shift(0.0), [])


def test_a_blend_of_two_restorers_erring_apart_is_scored_on_their_mean():
    clean = torch.full((1, 3, 8, 8), 0.5)
    pairs = [(clean, clean)]
    low, high = [clean - 0.1], [clean + 0.1]  # each 20 dB (MSE 0.01), their mean exact
    assert blend_psnr(low, high, pairs) == pytest.approx(120.0)
    assert blend_psnr(low, [clean - 0.3], pairs) == pytest.approx(-10 * np.log10(0.04), abs=1e-4)
    with pytest.raises(ValueError):
        blend_psnr(low, [], pairs)


def test_the_prior_is_chosen_only_when_its_mean_is_higher():
    # means: tuned 24.5, prior 24.0, blend 24.75
    folds = [FoldScore(0, 2, 24.0, 26.0, 25.5), FoldScore(1, 2, 25.0, 22.0, 24.0)]
    assert not choose_prior(folds)
    assert choose_prior([*folds, FoldScore(2, 2, 20.0, 23.0, 22.0)])  # 23.0 against 23.33
    assert not choose_prior([FoldScore(0, 1, 20.0, 20.0, 20.0)])  # a tie keeps the tuned restorer
    record = choice_record(folds, "tuned-one", "prior-one")
    assert record["chosen"] == "tuned-one" and record["tuned_psnr"] == 24.5 and record["prior_psnr"] == 24.0
    assert record["blend_psnr"] == 24.75 and record["consensus_restorer"] == "prior-one"  # the blend won
    assert [f["view"] for f in record["folds"]] == [0, 1]


def test_the_prior_repairs_the_second_model_only_where_the_blend_beats_the_tuned_restorer():
    kept = [FoldScore(0, 2, 24.0, 22.0, 23.9)]  # the blend below the tuned restorer: the run's own
    assert not choose_blend(kept) and choice_record(kept, "t", "p")["consensus_restorer"] == ""
    assert not choose_blend([FoldScore(0, 2, 24.0, 24.0, 24.0)])  # a tie: the run's own
    won = [FoldScore(0, 2, 24.0, 25.0, 26.0)]  # the prior chosen: it repairs both models anyway
    assert choose_prior(won) and not choose_blend(won)
    assert choice_record(won, "t", "p")["consensus_restorer"] == ""


def test_tune_step_scores_every_held_out_fold_and_resumes_them(
    upstream,
    tmp_path,
    tiny_cache,
    tiny_prior,
    monkeypatch,
):
    """Each fold: the tuned restorer and the prior on that view's leave-one-out pairs (the prior's score
    recomputed here); a rerun reads the folds back and only the final tuning runs again."""
    from go_core.compact import tuning
    from go_core.compact.restorer import load_restorer
    from go_core.repair.pairs import LooPairs, pair_tensors

    _, dirs = upstream
    ctx = _tune(tmp_path, dirs, CHOICE)
    choice = json.loads((ctx.out_dir / "tune.json").read_text())["choice"]
    loo = LooPairs(dirs["loo"])
    views = sorted({loo.get(i).view for i in range(len(loo))})
    assert [f["view"] for f in choice["folds"]] == views and len(views) >= 2
    prior = load_restorer("tiny-prior")
    first = [pair_tensors(loo.get(i), LORA["compact_resolution"], prior.channels) for i in range(len(loo))
             if loo.get(i).view == views[0]]  # fmt: skip
    assert choice["folds"][0]["prior_psnr"] == pytest.approx(restored_psnr(prior, first), abs=1e-4)
    assert choice["folds"][0]["tuned_psnr"] != choice["folds"][1]["tuned_psnr"]
    assert choice["chosen"] == ("tiny-prior" if choice["prior_psnr"] > choice["tuned_psnr"] else TUNED)
    blend_won = choice["chosen"] == TUNED and choice["blend_psnr"] > choice["tuned_psnr"]
    assert choice["consensus_restorer"] == ("tiny-prior" if blend_won else "")

    calls = []
    real = tuning.tune_compact
    monkeypatch.setattr(tuning, "tune_compact", lambda *a, **k: calls.append(1) or real(*a, **k))
    again = _tune(tmp_path, dirs, CHOICE)
    assert json.loads((again.out_dir / "tune.json").read_text())["choice"] == choice
    assert len(calls) == (choice["chosen"] == TUNED)  # the folds came from the checkpoint folder


def test_a_step_killed_between_folds_tunes_only_the_folds_left(
    upstream,
    tmp_path,
    tiny_cache,
    tiny_prior,
    monkeypatch,
):
    """Folds whose scores are in the checkpoint folder are not tuned again; the others are, and the
    choice is the uninterrupted one."""
    from go_core.compact import tuning

    _, dirs = upstream
    whole = json.loads((_tune(tmp_path / "whole", dirs, CHOICE).out_dir / "tune.json").read_text())["choice"]
    ctx = _tune(tmp_path / "killed", dirs, CHOICE)
    folder = ctx.checkpoint_dir / "restorer_choice"
    (folder / "fold_0.json").unlink()  # as if killed after the other folds
    (ctx.out_dir / "tune.json").unlink()
    calls = []
    real = tuning.tune_compact
    monkeypatch.setattr(tuning, "tune_compact", lambda *a, **k: calls.append(1) or real(*a, **k))
    again = _tune(tmp_path / "killed", dirs, CHOICE)
    assert json.loads((again.out_dir / "tune.json").read_text())["choice"] == whole
    assert len(calls) == 1 + (whole["chosen"] == TUNED)  # fold 0, then the final tuning if it is needed


@pytest.mark.parametrize(("choice_steps", "fold_steps"), [(2, 2), (50, LORA["compact_steps"])])
def test_each_fold_tunes_choice_steps_and_never_more_than_the_final_tuning(
    upstream, tmp_path, tiny_cache, tiny_prior, monkeypatch, choice_steps, fold_steps
):
    """The folds tune ``tune.choice_steps`` steps, capped at ``compact_steps``; the final tuning (where the
    tuned restorer is kept) tunes ``compact_steps`` whatever the folds did."""
    from go_core.compact import tuning

    steps = []
    real = tuning.tune_compact
    monkeypatch.setattr(tuning, "tune_compact", lambda *a, **k: steps.append(a[3].steps) or real(*a, **k))
    _, dirs = upstream
    ctx = _tune(tmp_path, dirs, {**CHOICE, "choice_steps": choice_steps})
    choice = json.loads((ctx.out_dir / "tune.json").read_text())["choice"]
    final = [LORA["compact_steps"]] if choice["chosen"] == TUNED else []
    assert steps == [fold_steps] * len(choice["folds"]) + final


@pytest.mark.parametrize(
    ("scores", "chosen", "second"),
    [
        ((20.0, 21.0, 20.5), "tiny-prior", "own"),  # the prior won: it repairs both models
        ((21.0, 20.0, 21.5), TUNED, "tiny-prior"),  # the tuned restorer kept, the blend won
        ((21.0, 20.0, 20.5), TUNED, "own"),  # the tuned restorer kept, the blend lost
    ],
)
def test_the_chosen_restorers_are_the_ones_the_repair_uses(
    upstream,
    tmp_path,
    tiny_cache,
    tiny_prior,
    monkeypatch,
    scores,
    chosen,
    second,
):
    from go_pipeline.steps import _repair_models

    def fold(ctx, inputs, params, name, views, view, held, prior):
        return FoldScore(view, len(held), *scores)

    monkeypatch.setattr(_repair_models, "_fold_score", fold)
    monkeypatch.setattr(_repair_models, "_prior_outputs", lambda *a: dict.fromkeys(a[-1], []))
    _, dirs = upstream
    tuned = _tune(tmp_path / "t", dirs, CHOICE)
    info = json.loads((tuned.out_dir / "tune.json").read_text())
    assert info["choice"]["chosen"] == chosen
    assert info["status"] == ("pretrained" if chosen != TUNED else "ok")
    assert info["compact"]["name"] == chosen
    assert (tuned.out_dir / "compact.safetensors").is_file() == (chosen == TUNED)
    params = {**REPAIR, "consensus": True, "coarse": {"iterations": 20, "checkpoint_every": 8}}
    repaired = json.loads(
        (_repair(tmp_path / "r", dirs, tuned.out_dir, params).out_dir / "repair.json").read_text()
    )
    assert repaired["compact_model"] == chosen
    assert repaired["lora"] == ("pretrained (no fine-tuning)" if chosen != TUNED else "fine-tuned")
    assert repaired["consensus"]["restorer"] == second  # repair.consensus_restorer: choice (the default)


def test_the_default_prior_choice_names_a_prior_shipped_in_the_package():
    from go_pipeline.steps.params import TuneParams

    from go_core.compact.prior import SHIPPED, SHIPPED_DIR

    name = TuneParams().prior_choice
    assert name in SHIPPED and (SHIPPED_DIR / f"{name}.safetensors").is_file()
