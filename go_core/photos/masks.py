"""Object masks of every photo of a photo folder (SfM restricts features to them; the views keep them).

* ``u2netp``: the auto masks (``go_core.scene.auto_mask``: the u2netp salient-object model from the weights
  cache with the post-processing chosen by measured IoU, docs/photo_masks.md);
* ``grabcut``: OpenCV GrabCut seeded from the image border (``go_core.scene.masking.grabcut_mask``), run at
  ``GRABCUT_SIZE`` on the long side and scaled back (bilinear, > 0.5);
* ``auto``: u2netp when it is in the weights cache (``go-pipeline weights fetch``), else GrabCut.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from go_core.scene.masking import grabcut_mask

PHOTO_MASK_METHODS = ("auto", "u2netp", "grabcut")
GRABCUT_SIZE = 400


def grabcut_photo_mask(image: np.ndarray, iterations: int = 5, border: float = 0.03) -> np.ndarray:
    """GrabCut at ``GRABCUT_SIZE`` px (long side), the mask scaled back to the image: {0, 1} float32."""
    import cv2

    h, w = image.shape[:2]
    s = min(1.0, GRABCUT_SIZE / max(h, w))
    small = cv2.resize(image, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    m = grabcut_mask(small, iterations, border)
    if s < 1.0:
        m = cv2.resize(m, (w, h), interpolation=cv2.INTER_LINEAR)
    return (m > 0.5).astype(np.float32)


def photo_masker(method: str, threads: int = 1) -> tuple[Callable[[np.ndarray], np.ndarray], str]:
    """(mask function, the method it is) for ``method`` in ``PHOTO_MASK_METHODS``; u2netp raises
    ``MissingWeightsError`` (naming the file and the fetch command) when asked for and not fetched."""
    if method not in PHOTO_MASK_METHODS:
        raise ValueError(f"photo mask method must be one of {PHOTO_MASK_METHODS}, got {method!r}")
    from go_core.scene.salient_weights import u2netp_path

    if method == "grabcut" or (method == "auto" and not u2netp_path().is_file()):
        return grabcut_photo_mask, "grabcut"
    from go_core.scene.auto_mask import auto_mask, load_segmenter

    segmenter = load_segmenter(threads=threads)
    return (lambda image: auto_mask(image, segmenter)), "u2netp"
