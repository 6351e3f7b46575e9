"""Post-processing of a salient-object map into an object mask: threshold, largest connected component,
hole filling, a box restriction, and GrabCut refinement seeded by the map (the choices and their measured
effect: docs/photo_masks.md)."""

from __future__ import annotations

import cv2
import numpy as np

from go_core.io.images import to_uint8

Box = tuple[float, float, float, float]  # x0, y0, x1, y1 in pixels (x1, y1 exclusive)


def largest_component(mask: np.ndarray) -> np.ndarray:
    """The 8-connected component of ``mask`` (bool) with the most pixels; empty stays empty."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if count <= 1:
        return np.zeros(mask.shape, bool)
    biggest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    return labels == biggest


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """``mask`` (bool) with every background region that does not touch the image border filled."""
    background = ~mask.astype(bool)
    count, labels = cv2.connectedComponents(background.astype(np.uint8), connectivity=4)
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    outside = np.isin(labels, border[border > 0])
    return ~outside if count > 1 else mask.astype(bool)


def box_mask(shape: tuple[int, int], box: Box) -> np.ndarray:
    """Bool [H,W]: True inside ``box`` (clipped to the image)."""
    h, w = shape
    x0, y0, x1, y1 = box
    out = np.zeros((h, w), bool)
    c0, r0 = max(0, int(np.floor(x0))), max(0, int(np.floor(y0)))
    c1, r1 = min(w, int(np.ceil(x1))), min(h, int(np.ceil(y1)))
    if c1 > c0 and r1 > r0:
        out[r0:r1, c0:c1] = True
    return out


def grabcut_refine(
    image: np.ndarray,
    saliency: np.ndarray,
    sure: float = 0.9,
    unsure: float = 0.1,
    iterations: int = 5,
    outside: np.ndarray | None = None,
) -> np.ndarray:
    """GrabCut (colour GMMs + graph cut) seeded by a saliency map: above ``sure`` is sure foreground, below
    ``unsure`` probable background, in between probable foreground/background by 0.5; ``outside`` (bool,
    optional) is sure background (e.g. outside the user's box). Returns bool [H,W]; the seeds are returned
    unchanged when GrabCut cannot run (no background or no foreground seed)."""
    seeds = np.where(saliency >= 0.5, cv2.GC_PR_FGD, cv2.GC_PR_BGD).astype(np.uint8)
    seeds[saliency >= sure] = cv2.GC_FGD
    seeds[saliency < unsure] = cv2.GC_BGD
    if outside is not None:
        seeds[outside] = cv2.GC_BGD
    fg = (seeds == cv2.GC_FGD) | (seeds == cv2.GC_PR_FGD)
    if not fg.any() or fg.all():
        return fg
    bgr = cv2.cvtColor(to_uint8(image)[..., :3], cv2.COLOR_RGB2BGR)
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(0)
    cv2.grabCut(bgr, seeds, None, bgd, fgd, int(iterations), cv2.GC_INIT_WITH_MASK)
    return (seeds == cv2.GC_FGD) | (seeds == cv2.GC_PR_FGD)
