"""Image-quality evaluation under the GaussianObject / 3DGS protocol.

* ground truth = the test photo composited on WHITE with its mask; renders use a white background;
* PSNR, SSIM (3DGS Gaussian window, zero-padded borders) and LPIPS v0.1 over the FULL image;
* LPIPS-vgg is the paper's LPIPS; it is also reported ×100 as ``lpips_star`` (the paper's LPIPS*);
  LPIPS-alex is reported alongside;
* optional masked metrics (``masked=True``): PSNR / SSIM / LPIPS averaged over the GT mask only (PSNR over
  mask pixels, SSIM map and LPIPS spatial map weighted by the mask).

LPIPS weights are never faked: a net without local weights is reported as unavailable (value None) together
with the reason and the command that fetches it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from go_core.errors import MissingWeightsError
from go_core.io.images import composite, to_uint8
from go_core.metrics.lpips import LPIPS
from go_core.metrics.psnr import psnr
from go_core.metrics.ssim import reduce_ssim_map, ssim_metric_map

LPIPS_NETS = ("vgg", "alex")
LPIPS_MIN_SIZE = {"alex": 32, "vgg": 16}  # smaller images vanish in the backbone's pooling: no value
__all__ = ["MetricSuite", "composite", "error_map", "mean_metrics"]
METRIC_KEYS = ("psnr", "ssim", "lpips_vgg", "lpips_alex", "lpips_star")


@dataclass
class MetricSuite:
    """The LPIPS models that could be loaded, and why the others could not."""

    lpips: dict[str, LPIPS] = field(default_factory=dict)
    unavailable: dict[str, str] = field(default_factory=dict)

    @staticmethod
    def load(nets: tuple[str, ...] | list[str] = LPIPS_NETS, root: Path | None = None) -> MetricSuite:
        suite = MetricSuite()
        for net in nets:
            try:
                suite.lpips[net] = LPIPS.from_cache(net, root)
            except MissingWeightsError as exc:
                suite.unavailable[net] = str(exc)
        return suite

    def status(self) -> dict[str, str]:
        out = {net: "ok" for net in self.lpips}
        out.update({net: f"unavailable: {why}" for net, why in self.unavailable.items()})
        return out

    def evaluate(
        self, pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None, masked: bool = False
    ) -> dict:
        """Metrics of one render ``pred`` against ``gt`` (both [H,W,3] in [0, 1], gt already composited).

        Returns {psnr, ssim, lpips_vgg, lpips_alex, lpips_star} (None where LPIPS is unavailable) and, when
        ``masked`` and a mask is given, the same under ``"masked"``.
        """
        p = torch.from_numpy(np.ascontiguousarray(pred, np.float32)).clamp(0, 1)
        g = torch.from_numpy(np.ascontiguousarray(gt, np.float32)).clamp(0, 1)
        m = None
        if masked and mask is not None:
            m = torch.from_numpy(np.ascontiguousarray(mask, np.float32))
        full, masked_lpips = self._lpips(p, g, m)
        smap = ssim_metric_map(p, g)
        out: dict = {"psnr": _finite(psnr(p, g)), "ssim": reduce_ssim_map(smap), **full}
        if m is not None:
            out["masked"] = {"psnr": _finite(psnr(p, g, m)), "ssim": reduce_ssim_map(smap, m), **masked_lpips}
        return out

    def _lpips(self, p: torch.Tensor, g: torch.Tensor, mask: torch.Tensor | None) -> tuple[dict, dict]:
        """Full-image LPIPS values and, with ``mask``, the mask-weighted means of the spatial maps (one
        backbone pass for both)."""
        full: dict[str, float | None] = {}
        part: dict[str, float | None] = {}
        a = p.permute(2, 0, 1)[None] * 2 - 1
        b = g.permute(2, 0, 1)[None] * 2 - 1
        for net in LPIPS_NETS:
            model = self.lpips.get(net)
            full[f"lpips_{net}"] = part[f"lpips_{net}"] = None
            if model is None or min(p.shape[0], p.shape[1]) < LPIPS_MIN_SIZE[net]:
                continue
            with torch.no_grad():
                dist, dmap = model.distance_and_map(a, b, spatial=mask is not None)
            full[f"lpips_{net}"] = float(dist[0])
            if mask is not None:
                w = mask.double()
                part[f"lpips_{net}"] = float((dmap[0, 0].double() * w).sum() / w.sum().clamp_min(1e-12))
        for vals in (full, part):
            vgg = vals.get("lpips_vgg")
            vals["lpips_star"] = None if vgg is None else 100.0 * vgg
        return full, part


def _finite(x: float) -> float | None:
    """JSON has no infinity: identical images (PSNR = inf) are stored as None."""
    return x if math.isfinite(x) else None


def mean_metrics(per_view: list[dict]) -> dict:
    """Mean of each metric over the views that have it (None when no view has it)."""
    out: dict = {}
    for key in METRIC_KEYS:
        vals = [v[key] for v in per_view if v.get(key) is not None]
        out[key] = float(np.mean(vals)) if vals else None
    masked = [v["masked"] for v in per_view if "masked" in v]
    if masked:
        out["masked"] = mean_metrics(masked)
    return out


def error_map(pred: np.ndarray, gt: np.ndarray, vmax: float = 0.5) -> np.ndarray:
    """A colour-coded per-pixel error image (uint8 [H,W,3]): mean absolute RGB error, 'magma' colormap,
    saturating at ``vmax``."""
    from matplotlib import colormaps

    err = np.abs(np.asarray(pred, np.float32) - np.asarray(gt, np.float32)).mean(-1)
    rgba = colormaps["magma"](np.clip(err / vmax, 0.0, 1.0))
    return to_uint8(rgba[..., :3])
