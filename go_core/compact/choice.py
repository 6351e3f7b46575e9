"""Which restorer repairs a scene: the run's restorer tuned on the scene's pairs, or a repair prior as
shipped, chosen on the scene's own held-out views (issues 33 and 34).

Neither wins everywhere. The tuned restorer corrects colours the coarse model gets wrong for this scene
(white_bowl, ethiopian_head); the prior, trained across scanned objects, is better where the coarse colours
are right and the shape is not (milk, blowtorch). The leave-one-out pairs are true novel views with their
photos, so they can judge: for each training view k the run's restorer is tuned as the tune step tunes it,
on every pair whose view is not k, and it and the prior restore view k's leave-one-out renders. The prior
is chosen when its PSNR against the photos, averaged over the folds, is higher (docs/repair_prior.md,
"Choosing the restorer per scene").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
import torch

from go_core.metrics.psnr import mse

Pairs = Sequence[tuple[torch.Tensor, torch.Tensor]]  # (degraded, clean) [1, C, r, r] in the square frame


@dataclass(frozen=True)
class FoldScore:
    """One held-out training view: the mean PSNR (dB) of each restorer's output on its leave-one-out pairs."""

    view: int
    pairs: int
    tuned_psnr: float
    prior_psnr: float


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    """PSNR (dB) of two images in [0, 1]: the eval's MSE (go_core.metrics.psnr), floored at 1e-12 so that a
    perfect restoration scores 120 dB, not infinity, and a fold's mean stays finite."""
    return float(-10.0 * np.log10(max(float(mse(a, b)), 1e-12)))


@torch.no_grad()
def restored_psnr(model: torch.nn.Module, pairs: Pairs) -> float:
    """Mean PSNR of ``model``'s restored RGB (clamped to [0, 1]; a prior's alpha is left out) against the
    clean RGB, over ``pairs``."""
    if not pairs:
        raise ValueError("no held-out pairs to score a restorer on")
    was = model.training
    model.eval()
    try:
        return float(np.mean([psnr(model(d).clamp(0.0, 1.0)[:, :3], c[:, :3]) for d, c in pairs]))
    finally:
        model.train(was)


def choose_prior(folds: Sequence[FoldScore]) -> bool:
    """True when the prior's PSNR averaged over the folds is above the tuned restorer's."""
    if not folds:
        raise ValueError("no folds to choose a restorer on")
    return float(np.mean([f.prior_psnr for f in folds])) > float(np.mean([f.tuned_psnr for f in folds]))


def choice_record(folds: Sequence[FoldScore], tuned: str, prior: str) -> dict:
    """tune.json's ``choice``: the two restorers, every fold's scores, their means and the one chosen."""
    return {
        "tuned": tuned,
        "prior": prior,
        "chosen": prior if choose_prior(folds) else tuned,
        "tuned_psnr": round(float(np.mean([f.tuned_psnr for f in folds])), 4),
        "prior_psnr": round(float(np.mean([f.prior_psnr for f in folds])), 4),
        "folds": [_rounded(asdict(f)) for f in folds],
    }


def _rounded(row: dict) -> dict:
    return {k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()}


__all__ = ["FoldScore", "choice_record", "choose_prior", "psnr", "restored_psnr"]
