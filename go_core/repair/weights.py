"""The two weights of the repair loss: distance-aware λ(π) and the DreamFusion timestep weight w(t)."""

from __future__ import annotations

import numpy as np
import torch


def neighbour_dmax(ref_positions: np.ndarray) -> float:
    """d_max: the largest distance between neighbouring reference views (positions given in arc order,
    cyclic). A view half-way between the two farthest neighbours then gets λ ≈ 1."""
    p = np.asarray(ref_positions, np.float64)
    if len(p) < 2:
        raise ValueError("d_max needs at least 2 reference views")
    d = np.linalg.norm(p - np.roll(p, -1, axis=0), axis=1)
    return float(d.max())


def distance_weight(position: np.ndarray, ref_positions: np.ndarray, d_max: float) -> float:
    """λ(π) = 2 · min_i ‖π − π_i‖ / d_max: small near a reference view (little to repair), larger far away."""
    d = np.linalg.norm(np.asarray(ref_positions, np.float64) - np.asarray(position, np.float64), axis=1)
    return float(2.0 * d.min() / d_max)


def dreamfusion_weight(alphas_cumprod: torch.Tensor | np.ndarray, t: int) -> float:
    """w(t) = σ_t² = 1 − ᾱ_t (the DreamFusion weighting), for an integer training timestep t."""
    a = alphas_cumprod[int(t)]
    return float(1.0 - (a.item() if isinstance(a, torch.Tensor) else a))


def lrep_decay(iteration: int, repair_iterations: int, start: float = 1.0, end: float = 0.1) -> float:
    """Weight of L_rep at ``iteration``: linear ``start`` → ``end`` over the repair iterations, then 0."""
    if iteration >= repair_iterations:
        return 0.0
    return float(start + (end - start) * iteration / max(repair_iterations - 1, 1))
