"""3D noise for degraded/clean training pairs (paper Sec. 3.4, Algorithm 1).

The leave-one-out runs give, per Gaussian, the change of each attribute when the left-out view is added
(N-view model minus (N−1)-view model). Their per-channel mean and std describe how a model trained on too few
views is "off"; adding Gaussian noise with those statistics to the coarse model's position, scale, rotation
and opacity (never its SH colours) and rendering it at a reference view gives a realistic degraded image
whose clean counterpart is the reference photo.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from go_core.gaussians import Gaussians

NOISED_ATTRIBUTES = ("means", "log_scales", "quats", "opacity_logits")


def _attribute(g: Gaussians, name: str) -> torch.Tensor:
    t = g.normalized_quats() if name == "quats" else getattr(g, name)
    return t.detach().to(torch.float64).reshape(len(g), -1)


@dataclass(frozen=True)
class NoiseStats:
    """Per-attribute, per-channel mean and std of parameter differences."""

    mean: dict[str, list[float]]
    std: dict[str, list[float]]
    count: int  # number of Gaussian differences the statistics come from

    def to_json(self) -> dict:
        return {
            "mean": self.mean,
            "std": self.std,
            "count": self.count,
            "attributes": list(NOISED_ATTRIBUTES),
        }

    @staticmethod
    def from_json(obj: dict) -> NoiseStats:
        return NoiseStats(
            {k: list(map(float, v)) for k, v in obj["mean"].items()},
            {k: list(map(float, v)) for k, v in obj["std"].items()},
            int(obj["count"]),
        )


def difference_stats(pairs: list[tuple[Gaussians, Gaussians]]) -> NoiseStats:
    """Statistics of ``after − before`` over every Gaussian of every (before, after) pair (same rows)."""
    diffs: dict[str, list[torch.Tensor]] = {k: [] for k in NOISED_ATTRIBUTES}
    for before, after in pairs:
        if len(before) != len(after):
            raise ValueError(f"difference pairs need matching Gaussians, got {len(before)} and {len(after)}")
        for k in NOISED_ATTRIBUTES:
            diffs[k].append(_attribute(after, k) - _attribute(before, k))
    if not pairs:
        raise ValueError("no leave-one-out pairs to take statistics from")
    mean, std = {}, {}
    for k, parts in diffs.items():
        d = torch.cat(parts)
        mean[k] = d.mean(0).tolist()
        std[k] = (d.std(0, unbiased=True) if len(d) > 1 else torch.zeros(d.shape[1], dtype=d.dtype)).tolist()
    return NoiseStats(mean, std, sum(len(b) for b, _ in pairs))


def add_noise(g: Gaussians, stats: NoiseStats, generator: torch.Generator, scale: float = 1.0) -> Gaussians:
    """A copy of ``g`` with N(mean, std²)·scale noise on position, log-scale, rotation and opacity logit."""
    out = {k: v.detach().clone() for k, v in g.tensors().items()}
    n = len(g)
    for k in NOISED_ATTRIBUTES:
        base = _attribute(g, k)
        mu = torch.tensor(stats.mean[k], dtype=torch.float64)
        sd = torch.tensor(stats.std[k], dtype=torch.float64)
        z = torch.randn((n, base.shape[1]), generator=generator, dtype=torch.float64)
        noisy = base + scale * (mu + sd * z)
        out[k] = noisy.reshape(out[k].shape).to(out[k].dtype)
    return Gaussians(**out)


class PairSchedule:
    """Algorithm 1: a noise pair with probability p_manual (starting at ``p0``, multiplied by ``decay`` each
    time a noise pair is used), else a cached leave-one-out pair. State is two numbers, so it checkpoints."""

    def __init__(self, p0: float, decay: float, has_loo_pairs: bool = True) -> None:
        self.p = float(p0)
        self.decay = float(decay)
        self.has_loo_pairs = has_loo_pairs
        self.noise_used = 0

    def draw(self, rng: np.random.Generator) -> str:
        """ "noise" or "loo" for the next training pair."""
        u = rng.random()
        if not self.has_loo_pairs or u < self.p:
            self.p *= self.decay
            self.noise_used += 1
            return "noise"
        return "loo"

    def state(self) -> dict:
        return {"p": self.p, "noise_used": self.noise_used}

    def load_state(self, s: dict) -> None:
        self.p, self.noise_used = float(s["p"]), int(s["noise_used"])
