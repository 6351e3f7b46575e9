"""Anti-aliased edges for binary masks.

A provided mask of a real capture is binary: each pixel is wholly object or wholly background, so a curved
or slanted outline becomes a staircase that the photometric loss asks the Gaussians to reproduce. A
rendered (or area-scaled) mask holds each edge pixel's covered fraction instead. ``smooth_binary_edges``
estimates that fraction from the binary mask alone: the mask is upsampled ``SUPERSAMPLING`` times, its
outline smoothed by a Gaussian of ``CONTOUR_SIGMA_PX`` pixels and thresholded at ½ (the staircase becomes
a curve through it), and the subpixels are averaged back to the pixel grid. Chosen on analytic shapes
against their exact pixel coverage (64 px images, 8 random shapes per family and seed): the mean absolute
coverage error relative to the binary mask's is 0.46-0.50 on discs, 0.50-0.61 on rotated squares and
0.47-0.78 on bars 1.5-5 px wide at σ 1.0 px (three seeds); 0.70-0.75 at 0.5 px; at 1.5 px the thin bars
are lost (1.00). ``tests/test_mask_edges.py`` holds the bounds. Pixels farther than about three pixels
from the outline keep their 0 or 1.
"""

from __future__ import annotations

import numpy as np

SUPERSAMPLING = 8  # subpixels per pixel side for the coverage estimate
CONTOUR_SIGMA_PX = 1.0  # outline smoothing, in pixels of the mask


def is_binary(mask: np.ndarray) -> bool:
    """True when every value of ``mask`` is exactly 0 or 1."""
    return bool(np.isin(mask, (0.0, 1.0)).all())


def smooth_binary_edges(mask: np.ndarray) -> np.ndarray:
    """[H, W] float32 coverage estimate of a binary ``mask``'s outline (a soft mask is returned as is)."""
    import cv2

    if not is_binary(mask):
        return mask.astype(np.float32, copy=False)
    h, w = mask.shape
    f = SUPERSAMPLING
    up = cv2.resize((mask * 255).astype(np.uint8), (w * f, h * f), interpolation=cv2.INTER_NEAREST)
    smooth = cv2.GaussianBlur(up, (0, 0), CONTOUR_SIGMA_PX * f, borderType=cv2.BORDER_REPLICATE)
    inside = smooth >= 128
    covered = inside.reshape(h, f, w, f).sum(axis=(1, 3), dtype=np.int32)
    return (covered / float(f * f)).astype(np.float32)
