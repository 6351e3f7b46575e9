"""Does a pair of feature matches that disagrees with the given poses describe poses the silhouettes allow?

A verified pair whose matches disagree with the given cameras is evidence that one of the two is wrong only
if turning that camera to fit the matches gives a pose the object's silhouettes accept. A rotationally
symmetric, textureless object (a bowl, a plate) is matched to itself across views by a confident learned
matcher: the matches pass COLMAP's two-view verification, yet the turn they ask for is 14-74° and carves the
visual hull away from the other views' masks (dev/white_bowl, all 24 views with correct poses: mask coverage
1.000 under the given poses, at most 0.78 after either turn). A camera that really is turned asks for its
true error back (dev/milk, a view turned 5°: 3.6-5.1° on 6 of its 7 pairs within 45°) and the masks agree
better after the turn than before (lowest coverage 0.84 → 0.86-1.00). docs/evaluation.md has the data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from go_core.camera import Camera
from go_core.errors import EmptyHullError
from go_core.poses.epipolar import epipolar_distances

COVERAGE_PIXELS = 300  # mask pixels drawn per view for each coverage of a turned camera (seeded)
COVERAGE_SAMPLES = 128  # samples per ray
COVERAGE_TOLERANCE = 0.02  # a turn may lower the lowest coverage this much and still count (sampling noise)


def refutation_floor(given_lowest: float, min_coverage: float) -> float:
    """The lowest mask coverage a turn must leave for its pair to count: as good as the given poses' (at
    most ``min_coverage``, the level at which masks agree), less ``COVERAGE_TOLERANCE``. With one camera
    wrong the given coverage is already low, and its pairs' turns (back towards the truth) raise it, while
    self-matches still carve it away."""
    return min(given_lowest, min_coverage) - COVERAGE_TOLERANCE


def turn_to_matches(
    cameras: tuple[Camera, Camera], points: tuple[np.ndarray, np.ndarray], which: int, scale_px: float
) -> tuple[Camera, float, float]:
    """Turn camera ``which`` (0 or 1) of the pair about its centre, the other held, to minimise the robust
    (soft-L1, ``scale_px``) epipolar distances of the matched ``points`` [N,2] of each view.

    Returns the turned camera, the turn in degrees and the median epipolar distance after it."""
    from scipy.optimize import least_squares

    def residuals(rotvec: np.ndarray) -> np.ndarray:
        pair = list(cameras)
        pair[which] = cameras[which].turned(rotvec)
        return epipolar_distances(pair[0], pair[1], points[0], points[1])

    fit = least_squares(residuals, np.zeros(3), loss="soft_l1", f_scale=scale_px)
    return (
        cameras[which].turned(fit.x),
        float(np.degrees(np.linalg.norm(fit.x))),
        float(np.median(residuals(fit.x))),
    )


def lowest_coverage(cameras: list[Camera], masks: list[np.ndarray]) -> float:
    """The lowest mask coverage of any view (``go_core.poses.verify.mask_coverage``); 0 when the masks'
    frusta have no common point."""
    from go_core.poses.verify import mask_coverage

    try:
        cov = mask_coverage(cameras, masks, max_pixels=COVERAGE_PIXELS, samples_per_ray=COVERAGE_SAMPLES)
    except EmptyHullError:
        return 0.0
    return float(min(cov))


@dataclass
class PairTurns:
    """What the two turns a disagreeing pair asks for do to the silhouettes (one entry per view)."""

    turn_deg: tuple[float, float]
    coverage: tuple[float, float]  # lowest mask coverage of any view with that view turned

    def refuted(self, floor: float) -> bool:
        """Neither turn leaves every view's coverage at or above ``floor`` (``refutation_floor``)."""
        return max(self.coverage) < floor


def pair_turns(
    cameras: list[Camera],
    masks: list[np.ndarray],
    pair: tuple[int, int],
    points: tuple[np.ndarray, np.ndarray],
    scale_px: float,
    floor: float,
) -> PairTurns:
    """For the disagreeing ``pair`` (i, j) with matched ``points`` (pixels in i, in j): turn i to fit the
    matches with j held, then j with i held, and measure the masks' agreement after each. The second turn is
    skipped (coverage 0) when the first already leaves every view's coverage >= ``floor``."""
    turns, covs = [0.0, 0.0], [0.0, 0.0]
    for which in (0, 1):
        cam, turns[which], _ = turn_to_matches((cameras[pair[0]], cameras[pair[1]]), points, which, scale_px)
        trial = list(cameras)
        trial[pair[which]] = cam
        covs[which] = lowest_coverage(trial, masks)
        if covs[which] >= floor:
            break
    return PairTurns(tuple(turns), tuple(covs))
