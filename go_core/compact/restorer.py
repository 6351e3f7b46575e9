"""A pretrained super-resolution network used as a same-size image restorer (the compact repair model).

``restore(x)`` takes a render [B, 3, H, W] in [0, 1] (object on white). Mode ``down_up``: area-downsample
by the network's scale s (which removes the coarse model's high-frequency artefacts: ghost edges, speckle)
and let the network re-synthesise the detail at the original size. Mode ``up_down``: run the network at
full resolution and area-average its s-times output back (a denoise/sharpen at the render's own scale).
One pass, no sampling; differentiable, so the same module is fine-tuned per scene
(``go_core.compact.tuning``) and used by the repair loop.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from go_core.compact.ncnn import NcnnNet

MODES = ("down_up", "up_down")


class CompactRestorer(nn.Module):
    channels = 3  # RGB on white in and out (a repair prior takes and gives alpha too: 4)

    def __init__(
        self, net: NcnnNet, scale: int, prepad: int = 0, name: str = "", mode: str = "down_up"
    ) -> None:
        super().__init__()
        if mode not in MODES:
            raise ValueError(f"restorer mode must be one of {MODES}, got {mode!r}")
        self.net = net
        self.scale = int(scale)
        self.prepad = int(prepad)
        self.name = name
        self.mode = mode

    @staticmethod
    def load(name: str, root=None, mode: str = "down_up") -> CompactRestorer:
        """The pretrained model ``name`` from the cache (MissingWeightsError when absent or corrupt)."""
        from go_core.compact.weights import load_compact

        net, meta = load_compact(name, root)
        return CompactRestorer(net, meta["scale"], meta["prepad"], name, mode)

    def tuned_tensors(self) -> dict[str, torch.Tensor]:
        """The weights a per-scene tuning changes, in the ncnn layout, for the tune step's file."""
        return {k: v.contiguous() for k, v in self.net.ncnn_tensors().items()}

    def load_tuned(self, tensors: dict[str, torch.Tensor]) -> None:
        self.net.load_ncnn_tensors(tensors)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        s = self.scale
        if self.mode == "up_down":  # the network at full resolution, its s-times output area-averaged back
            xp = F.pad(x, (self.prepad,) * 4, mode="replicate") if self.prepad else x
            return F.interpolate(self.net(xp), size=(h, w), mode="area")
        small = F.interpolate(x, size=(max(1, round(h / s)), max(1, round(w / s))), mode="area")
        if self.prepad:
            p = self.prepad
            small = F.pad(small, (p, p, p, p), mode="replicate")
        y = self.net(small)
        if y.shape[-2:] != (h, w):
            y = F.interpolate(y, size=(h, w), mode="bilinear", align_corners=False)
        return y

    @torch.no_grad()
    def restore(self, x: torch.Tensor) -> torch.Tensor:
        """Inference: ``forward`` clamped to [0, 1], in eval mode."""
        was = self.training
        self.eval()
        try:
            return self(x).clamp(0.0, 1.0)
        finally:
            self.train(was)


def load_restorer(name: str) -> nn.Module:
    """The compact repair model ``name``: a shipped repair prior (``go_core.compact.prior.SHIPPED``, RGB +
    alpha) or a converted pretrained network (RGB). Either has ``channels``, ``scale``, ``restore``,
    ``tuned_tensors`` and ``load_tuned``; missing or corrupt weights are one MissingWeightsError."""
    from go_core.compact.prior import SHIPPED, PriorRestorer

    return PriorRestorer.load(name) if name in SHIPPED else CompactRestorer.load(name)
