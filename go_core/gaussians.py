"""The Gaussian parameter set (raw, unconstrained parameters) and its activations.

Storage convention (INRIA 3DGS / gsplat): ``quats`` are w-first and may be unnormalised, ``log_scales`` are
natural logs, ``opacity_logits`` go through a sigmoid, ``sh`` holds degree-0..D spherical-harmonic
coefficients as [N, (D+1)², 3] (DC first). Colour = SH·basis + 0.5, clamped at 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch

from go_core.sh import SH_C0, num_sh_bases


def rgb_to_sh0(rgb: torch.Tensor) -> torch.Tensor:
    """DC coefficient giving colour ``rgb`` (in [0, 1]) in every direction."""
    return (rgb - 0.5) / SH_C0


def sh0_to_rgb(sh0: torch.Tensor) -> torch.Tensor:
    return sh0 * SH_C0 + 0.5


def sh_degree_of(num_bases: int) -> int:
    degree = round(num_bases**0.5) - 1
    if num_bases != (degree + 1) ** 2:
        raise ValueError(f"{num_bases} is not a square number of SH coefficients")
    return degree


MAX_LOG_SCALE = math.log(1e20)  # larger Gaussians overflow the projected covariance (float32): dropped


def _invalid(what: str, problem: str, bad: torch.Tensor, where: str | Path | None):
    from go_core.errors import InvalidGaussiansError

    idx = torch.nonzero(bad).flatten()
    return InvalidGaussiansError(
        f"{len(idx)} of {len(bad)} Gaussians have {what} {problem} (first: index {int(idx[0])}); "
        "the model cannot be rendered",
        where,
    )


@dataclass
class Gaussians:
    """N Gaussians as raw tensors; every field's first dimension is N."""

    means: torch.Tensor  # [N, 3]
    quats: torch.Tensor  # [N, 4] (w, x, y, z), unnormalised
    log_scales: torch.Tensor  # [N, 3]
    opacity_logits: torch.Tensor  # [N]
    sh: torch.Tensor  # [N, (D+1)^2, 3]

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        for f in fields(self):
            t = getattr(self, f.name)
            if t.shape[0] != n:
                raise ValueError(f"Gaussians.{f.name} has {t.shape[0]} rows, means has {n}")

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        return sh_degree_of(self.sh.shape[1])

    # Activations -----------------------------------------------------------------------------------------
    def scales(self) -> torch.Tensor:
        return torch.exp(self.log_scales)

    def opacities(self) -> torch.Tensor:
        return torch.sigmoid(self.opacity_logits)

    def normalized_quats(self) -> torch.Tensor:
        return torch.nn.functional.normalize(self.quats, dim=-1)

    # Construction and selection --------------------------------------------------------------------------
    @staticmethod
    def from_points(
        points: torch.Tensor, colors: torch.Tensor, scales: torch.Tensor, opacity: float, sh_degree: int
    ) -> Gaussians:
        """Isotropic Gaussians at ``points`` with RGB ``colors`` (DC only), per-point ``scales`` [N]."""
        n = points.shape[0]
        sh = torch.zeros(n, num_sh_bases(sh_degree), 3, dtype=points.dtype)
        sh[:, 0] = rgb_to_sh0(colors)
        quats = torch.zeros(n, 4, dtype=points.dtype)
        quats[:, 0] = 1.0
        log_scales = torch.log(scales.clamp_min(1e-12)).reshape(n, 1).expand(n, 3).clone()
        logit = float(np.log(opacity / (1.0 - opacity)))
        return Gaussians(points.clone(), quats, log_scales, torch.full((n,), logit, dtype=points.dtype), sh)

    def tensors(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def map(self, fn) -> Gaussians:
        """A new set with ``fn`` applied to every tensor (e.g. ``lambda t: t[mask]``)."""
        return Gaussians(**{k: fn(v) for k, v in self.tensors().items()})

    def select(self, index: torch.Tensor) -> Gaussians:
        return self.map(lambda t: t[index])

    def detach(self) -> Gaussians:
        return self.map(lambda t: t.detach().clone())

    def to(self, device=None, dtype=None) -> Gaussians:
        return self.map(lambda t: t.to(device=device, dtype=dtype))

    def with_sh_degree(self, degree: int) -> Gaussians:
        """Pad with zeros or truncate the SH coefficients to ``degree``."""
        k = num_sh_bases(degree)
        sh = self.sh
        if sh.shape[1] >= k:
            sh = sh[:, :k]
        else:
            sh = torch.cat([sh, sh.new_zeros(len(self), k - sh.shape[1], 3)], dim=1)
        return Gaussians(self.means, self.quats, self.log_scales, self.opacity_logits, sh.contiguous())

    @staticmethod
    def cat(parts: list[Gaussians]) -> Gaussians:
        names = [f.name for f in fields(Gaussians)]
        return Gaussians(**{k: torch.cat([getattr(p, k) for p in parts]) for k in names})

    # Storage (deterministic bytes for equal content) -----------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Write a deterministic ``.npz`` atomically (float32)."""
        from go_core.io.npz import write_npz_deterministic

        arrays = {k: v.detach().cpu().to(torch.float32).numpy() for k, v in self.tensors().items()}
        return write_npz_deterministic(path, arrays)

    @staticmethod
    def load(path: str | Path) -> Gaussians:
        """Read a ``.npz`` written by ``save``; ``InvalidGaussiansError`` (naming the file) when its
        parameters cannot be rendered (see ``check_renderable``)."""
        with np.load(path, allow_pickle=False) as data:
            g = Gaussians(**{f.name: torch.from_numpy(data[f.name].copy()) for f in fields(Gaussians)})
        g.check_renderable(path)
        return g

    def check_renderable(self, where: str | Path | None = None) -> None:
        """One clear error for parameters the rasterizer would turn into NaN gradients or silently drop:
        non-finite means, quaternions, opacities or colours, and scales that are not finite or >= 1e20.
        Called where a step starts (loading Gaussians, starting an optimisation), not per render."""
        checks = (
            ("means", self.means),
            ("quaternions", self.quats),
            ("opacities", self.opacity_logits),
            ("colours (SH)", self.sh),
        )
        for what, t in checks:
            bad = ~torch.isfinite(t.detach()).reshape(len(t), -1).all(1)
            if bool(bad.any()):
                raise _invalid(what, "not finite (NaN or inf)", bad, where)
        log_s = self.log_scales.detach()
        bad = ~(torch.isfinite(log_s) & (log_s < MAX_LOG_SCALE)).all(1)
        if bool(bad.any()):
            raise _invalid("scales", "not finite or >= 1e20", bad, where)
