"""Which restorer repairs a scene: the run's restorer tuned on the scene's pairs, or a repair prior as
shipped, chosen on the scene's own held-out views (issues 33 and 34).

Neither wins everywhere. The tuned restorer corrects colours the coarse model gets wrong for this scene
(white_bowl, ethiopian_head); the prior, trained across scanned objects, is better where the coarse colours
are right and the shape is not (milk, blowtorch). The leave-one-out pairs are true novel views with their
photos, so they can judge: for each training view k the run's restorer is tuned as the tune step tunes it,
on every pair whose view is not k, and it and the prior restore view k's leave-one-out renders. The prior
is chosen when its PSNR against the photos, averaged over the folds, is higher (docs/repair_prior.md,
"Choosing the restorer per scene").

Where the tuned restorer is kept, the folds also score the mean of both restorers' outputs: when that
blend beats the tuned restorer alone, the two kinds of repair err differently on this scene, and the
repair's second model (``repair.consensus``) is repaired by the prior, so that what both models render
is their agreement (``consensus_restorer``; docs/real_captures.md).
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
    blend_psnr: float  # the mean of both restorers' outputs


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    """PSNR (dB) of two images in [0, 1]: the eval's MSE (go_core.metrics.psnr), floored at 1e-12 so that a
    perfect restoration scores 120 dB, not infinity, and a fold's mean stays finite."""
    return float(-10.0 * np.log10(max(float(mse(a, b)), 1e-12)))


@torch.no_grad()
def restored(model: torch.nn.Module, pairs: Pairs) -> list[torch.Tensor]:
    """``model``'s restored RGB of each pair's degraded input, clamped to [0, 1] (a prior's alpha is left
    out), in eval mode."""
    if not pairs:
        raise ValueError("no held-out pairs to score a restorer on")
    was = model.training
    model.eval()
    try:
        return [model(d).clamp(0.0, 1.0)[:, :3] for d, _ in pairs]
    finally:
        model.train(was)


def mean_psnr(outputs: Sequence[torch.Tensor], pairs: Pairs) -> float:
    """Mean PSNR of ``outputs`` against the clean RGB of ``pairs``, pair by pair."""
    return float(np.mean([psnr(o, c[:, :3]) for o, (_, c) in zip(outputs, pairs, strict=True)]))


def blend_psnr(first: Sequence[torch.Tensor], second: Sequence[torch.Tensor], pairs: Pairs) -> float:
    """Mean PSNR of the mean of two restorers' outputs of the same pairs."""
    return mean_psnr([0.5 * (a + b) for a, b in zip(first, second, strict=True)], pairs)


def choose_prior(folds: Sequence[FoldScore]) -> bool:
    """True when the prior's PSNR averaged over the folds is above the tuned restorer's."""
    if not folds:
        raise ValueError("no folds to choose a restorer on")
    return float(np.mean([f.prior_psnr for f in folds])) > float(np.mean([f.tuned_psnr for f in folds]))


def choose_blend(folds: Sequence[FoldScore]) -> bool:
    """True when the tuned restorer is kept and the blend's PSNR averaged over the folds is above its own."""
    tuned = float(np.mean([f.tuned_psnr for f in folds]))
    return not choose_prior(folds) and float(np.mean([f.blend_psnr for f in folds])) > tuned


def choice_record(folds: Sequence[FoldScore], tuned: str, prior: str) -> dict:
    """tune.json's ``choice``: the two restorers, every fold's scores, their means, the one chosen and the
    restorer of the consensus's second model (the prior where the blend won, else '': the run's own)."""
    return {
        "tuned": tuned,
        "prior": prior,
        "chosen": prior if choose_prior(folds) else tuned,
        "consensus_restorer": prior if choose_blend(folds) else "",
        "tuned_psnr": round(float(np.mean([f.tuned_psnr for f in folds])), 4),
        "prior_psnr": round(float(np.mean([f.prior_psnr for f in folds])), 4),
        "blend_psnr": round(float(np.mean([f.blend_psnr for f in folds])), 4),
        "folds": [_rounded(asdict(f)) for f in folds],
    }


def _rounded(row: dict) -> dict:
    return {k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()}


__all__ = [
    "FoldScore",
    "blend_psnr",
    "choice_record",
    "choose_blend",
    "choose_prior",
    "mean_psnr",
    "psnr",
    "restored",
]
