"""Floater elimination (GaussianObject Sec. 3.3): drop Gaussians far from their neighbours.

For P Gaussians, each one's mean Euclidean distance to its ⌊√P⌋ nearest other Gaussians is d_i; those with
``d_i > mean(d) + λe·std(d)`` are removed. λe follows a linear schedule over the elimination window:
* ``"code"``: the authors' released code, rising 1 → 2.33 (z-score of the 99th percentile), so fewer are
  removed as the cloud gets denser;
* ``"paper"``: the paper's text, falling linearly to 0 (from ``1``), so more are removed over time.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial import cKDTree

SCHEDULES = {"code": (1.0, 2.33), "paper": (1.0, 0.0)}


@dataclass
class FloaterConfig:
    enabled: bool = True
    every: int = 500
    start_iter: int = 500  # the schedule's start (λ = its first value here)
    stop_iter: int = 6000  # last step at which it runs (λ = its last value here)
    schedule: str = "code"  # "code" (1 → 2.33) or "paper" (1 → 0)
    max_remove_fraction: float = 0.5  # safety: never remove more than this share in one pass

    def __post_init__(self) -> None:
        if self.schedule not in SCHEDULES:
            raise ValueError(f"floater schedule must be one of {sorted(SCHEDULES)}, got {self.schedule!r}")

    def to_dict(self) -> dict:
        return asdict(self)

    def due(self, step: int) -> bool:
        return (
            self.enabled
            and self.every > 0
            and step % self.every == 0
            and self.start_iter <= step <= self.stop_iter
        )

    def lambda_at(self, step: int) -> float:
        lo, hi = SCHEDULES[self.schedule]
        span = max(self.stop_iter - self.start_iter, 1)
        t = min(max((step - self.start_iter) / span, 0.0), 1.0)
        return lo + (hi - lo) * t


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
