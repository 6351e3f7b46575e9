"""Square framing of images for the repair model, keeping the object's aspect ratio.

SD1.5 works on square images whose side is a multiple of 64. A view is put into a square *frame* (a box in
image pixels, possibly larger than the image: the outside is filled with the background colour), resized to
``size``; after repair the square is resized back and the in-image part pasted. When the object's bounding
box fits inside the centred square of side min(H, W), that square is used (centre crop: more pixels on the
object); otherwise the image is padded to a square of side max(H, W). Both keep the aspect ratio.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F


@dataclass(frozen=True)
class Frame:
    """A square box ``[x0, x0 + side) × [y0, y0 + side)`` in the pixels of an ``height × width`` image."""

    x0: int
    y0: int
    side: int
    width: int
    height: int

    @staticmethod
    def choose(
        height: int, width: int, mask: np.ndarray | torch.Tensor | None = None, threshold: float = 0.5
    ) -> Frame:
        small, big = min(height, width), max(height, width)
        if mask is not None and height != width:
            m = np.asarray(mask.detach().cpu() if isinstance(mask, torch.Tensor) else mask).reshape(
                height, width
            )
            ys, xs = np.nonzero(m > threshold)
            x0, y0 = (width - small) // 2, (height - small) // 2
            if len(xs) == 0 or (
                xs.min() >= x0 and xs.max() < x0 + small and ys.min() >= y0 and ys.max() < y0 + small
            ):
                return Frame(x0, y0, small, width, height)
        return Frame((width - big) // 2, (height - big) // 2, big, width, height)

    def to_square(self, images: torch.Tensor, size: int, background: float = 1.0) -> torch.Tensor:
        """[B, C, H, W] → [B, C, size, size]: the frame's content, outside filled with ``background``."""
        b, c = images.shape[:2]
        canvas = images.new_full((b, c, self.side, self.side), background)
        sx0, sy0 = max(self.x0, 0), max(self.y0, 0)
        sx1, sy1 = min(self.x0 + self.side, self.width), min(self.y0 + self.side, self.height)
        canvas[:, :, sy0 - self.y0 : sy1 - self.y0, sx0 - self.x0 : sx1 - self.x0] = images[
            :, :, sy0:sy1, sx0:sx1
        ]
        if self.side == size:
            return canvas
        return F.interpolate(
            canvas, size=(size, size), mode="bilinear", align_corners=False, antialias=self.side > size
        )

    def from_square(self, square: torch.Tensor, base: torch.Tensor) -> torch.Tensor:
        """Paste a [B, C, s, s] square back into (a copy of) ``base`` [B, C, H, W]."""
        if square.shape[-1] != self.side:
            square = F.interpolate(
                square,
                size=(self.side, self.side),
                mode="bilinear",
                align_corners=False,
                antialias=square.shape[-1] > self.side,
            )
        out = base.clone()
        sx0, sy0 = max(self.x0, 0), max(self.y0, 0)
        sx1, sy1 = min(self.x0 + self.side, self.width), min(self.y0 + self.side, self.height)
        out[:, :, sy0:sy1, sx0:sx1] = square[
            :, :, sy0 - self.y0 : sy1 - self.y0, sx0 - self.x0 : sx1 - self.x0
        ]
        return out
