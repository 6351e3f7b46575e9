"""Floater elimination (GaussianObject Sec. 3.3): drop Gaussians far from their neighbours.

For P Gaussians, each one's mean Euclidean distance to its ⌊√P⌋ nearest other Gaussians is d_i; those with
``d_i > mean(d) + λe·std(d)`` are removed. λe follows a linear schedule over the elimination window:
* ``"code"``: the authors' released code, rising 1 → 2.33 (z-score of the 99th percentile), so fewer are
  removed as the cloud gets denser;
* ``"paper"``: the paper's text, falling linearly to 0 (from ``1``), so more are removed over time.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from go_core.coarse.settings import SCHEDULES, FloaterConfig

__all__ = ["SCHEDULES", "FloaterConfig", "FloaterElimination", "floater_mask", "knn_mean_distance"]


def knn_mean_distance(points: np.ndarray, k: int | None = None) -> np.ndarray:
    """Mean Euclidean distance of each point to its ``k`` nearest other points (default ⌊√P⌋)."""
    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    if n < 2:
        return np.zeros(n)
    k = int(np.sqrt(n)) if k is None else int(k)
    k = max(1, min(k, n - 1))
    dist, _ = cKDTree(pts).query(pts, k=k + 1, workers=-1)
    return dist[:, 1:].mean(axis=1)  # the first neighbour is the point itself


def floater_mask(
    points: np.ndarray, lambda_e: float, k: int | None = None, max_fraction: float = 1.0
) -> np.ndarray:
    """Boolean [P]: True for the Gaussians to REMOVE (d_i > mean + λe·std); at most ``max_fraction`` of them,
    the farthest first."""
    d = knn_mean_distance(points, k)
    if len(d) < 3:
        return np.zeros(len(d), dtype=bool)
    remove = d > d.mean() + lambda_e * d.std()
    limit = int(np.floor(max_fraction * len(d)))
    if remove.sum() > limit:
        order = np.argsort(-d, kind="stable")
        remove = np.zeros(len(d), dtype=bool)
        remove[order[:limit]] = True
    return remove


class FloaterElimination:
    """Floater elimination as a training strategy: at each step of ``config``'s schedule (``floater_due``),
    the Gaussians ``floater_mask`` flags are removed from the optimiser and the densification strategy is
    told which were kept. ``after_step`` returns that pass's record (None when none was due)."""

    def __init__(self, config: FloaterConfig) -> None:
        self.config = config

    def after_step(self, step: int, opt, densify) -> dict | None:
        """``opt``: the ``GaussianOptimizer``; ``densify``: the ``Strategy`` whose statistics follow."""
        if not self.config.floater_due(step):
            return None
        import torch

        lam = self.config.floater_lambda_at(step)
        means = opt.params["means"].detach().numpy()
        remove = floater_mask(means, lam, max_fraction=self.config.floater_max_remove_fraction)
        removed = int(remove.sum())
        if removed:
            keep = torch.from_numpy(~remove)
            opt.keep(keep)
            densify.on_external_prune(keep)
        return {"step": step, "lambda": round(lam, 6), "removed": removed, "remaining": len(opt)}
