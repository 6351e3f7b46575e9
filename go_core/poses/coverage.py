"""Silhouette coverage: how much of a view's mask the visual hull of the other views covers.

For a view's mask pixel, the ray through it is sampled evenly over its stretch inside a box that holds the
object; at each sample the *occupancy* is the product of the other views' mask values where the sample
projects, and the pixel's coverage is the largest occupancy along the ray (1: the ray meets the others'
hull). With consistent poses and masks every mask is covered (a visual hull contains the object); a
turned camera carves part of the others' hull away. The one definition of this quantity, used by

* the pose checks (``go_core.poses.verify.mask_coverage``): hard masks (thresholded, so occupancy is 0 or
  1), a seeded draw of mask pixels, numpy cameras;
* the silhouette alignment (``go_core.poses.silhouette_align``): blurred masks and differentiable cameras,
  so the coverage is a loss that turns and moves them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from go_core.camera import Camera
from go_core.coarse.hull import inside_masks, ray_box


def ray_coverage(
    origin: torch.Tensor,
    dirs: torch.Tensor,
    box: tuple,
    samples: int,
    occupancy: Callable[[torch.Tensor], torch.Tensor],
) -> torch.Tensor:
    """Per ray [R]: the largest ``occupancy`` at ``samples`` points spread evenly over the stretch of the
    ray (``origin`` [3], unit ``dirs`` [R,3]) inside ``box`` (lo, hi), 0 for a ray that misses the box.

    ``occupancy`` maps world points [N,3] to the product of the other views' mask values [N] (module
    docstring); gradients flow through ``origin``, ``dirs`` and ``occupancy``, not through the box."""
    frac = (torch.arange(samples, dtype=dirs.dtype) + 0.5) / samples
    with torch.no_grad():
        near, far = (
            torch.from_numpy(d)
            for d in ray_box(*(torch.as_tensor(v).detach().numpy() for v in (origin, dirs, *box)))
        )
        hit = far > near
        t = near[:, None] + frac[None] * (far - near).clamp_min(0.0)[:, None]  # [R,S]
    x = origin + t[..., None] * dirs[:, None, :]  # [R,S,3]
    return occupancy(x.reshape(-1, 3)).view(x.shape[:2]).amax(1) * hit


def hard_occupancy(
    cameras: list[Camera], masks: list[np.ndarray], threshold: float
) -> Callable[[torch.Tensor], torch.Tensor]:
    """Occupancy of the hull of ``cameras``' thresholded ``masks`` (1 where a point projects inside every
    mask: ``go_core.coarse.hull.inside_masks``), for ``ray_coverage``."""

    def occupancy(points: torch.Tensor) -> torch.Tensor:
        inside = inside_masks(points.numpy(), cameras, masks, threshold).all(0)
        return torch.from_numpy(inside).to(points.dtype)

    return occupancy
