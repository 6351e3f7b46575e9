"""Do the photos' SfM poses agree with their masks? A wrong pose passes COLMAP's own checks (its points
reproject well) when the features it rests on are wrong, e.g. a turntable disc's rim that looks the same in
every photo (issue 32: on a 66-photo turntable capture, 640-px SIFT posed the 6 photos whose auto masks took
in the disc up to 50° off, with a 0.51 px mean reprojection error). This check caught 4 of those 6 (median
rotation error 3.60° -> 0.94° after the rerun, one photo still 30° off); it cannot see a pose that looks at
the object from a wrong azimuth where the silhouette is alike (benchmarks/results/
photos_sfm_ethiopian_head.json).

The test: the voxels of the visual hull that the posed photos vote for (``hull_vote_voxels``: a voxel stays
when 75 % of the photos that see it mask it, so a few wrong photos cannot carve it, and what a few masks
take in too much is not in it) are projected into each
photo; with a right pose they land inside its own mask, even a mask that takes in too much (a disc, a
stand); with a wrong pose many land beside the object. Photos whose mask holds less than
``MIN_POSE_AGREEMENT`` times the share that the median photo's holds are left out, and SfM is run again
without them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from go_core.errors import PoseCheckError
from go_core.photos.sfm import SfmOutcome, SfmPhoto

MIN_POSE_AGREEMENT = 0.85  # a photo's agreement, relative to the median photo's, below which it disagrees
AGREEMENT_VOTE = 0.75  # the hull's vote: a quarter of the photos may be wrong without carving it
AGREEMENT_ROUNDS = 3  # SfM runs again without the disagreeing photos at most this many times


def pose_agreement(masks: list[np.ndarray], cameras: list) -> list[float]:
    """For each photo: the share of the voted hull's voxels whose centres project inside its own mask
    (1: agrees; a voxel outside the image counts as outside)."""
    from go_core.errors import EmptyHullError
    from go_core.scene.auto_mask import hull_vote_voxels

    try:
        kept, _ = hull_vote_voxels(masks, cameras, vote=AGREEMENT_VOTE)
    except EmptyHullError:
        return [0.0] * len(masks)  # no region that the photos agree on: no pose can be trusted
    if not len(kept):
        return [0.0] * len(masks)
    out = []
    for mask, cam in zip(masks, cameras, strict=True):
        uv, z = cam.project(kept)
        col, row = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        ok = (z > 0) & (col >= 0) & (col < mask.shape[1]) & (row >= 0) & (row < mask.shape[0])
        out.append(float((mask[row[ok], col[ok]] > 0.5).sum() / len(kept)))
    return out


def disagreeing(names: list[str], masks: list[np.ndarray], cameras: list) -> dict[str, float]:
    """{name: agreement / the median agreement} of the photos below ``MIN_POSE_AGREEMENT`` (empty when every
    pose agrees). Relative: the loose hull holds voxels that some right photos see beside the object too."""
    agreement = np.asarray(pose_agreement(masks, cameras))
    median = float(np.median(agreement))
    if median <= 0:
        return {n: 0.0 for n in names}
    relative = agreement / median
    return {n: round(float(r), 4) for n, r in zip(names, relative, strict=True) if r < MIN_POSE_AGREEMENT}


def sfm_agreeing(
    photos: list[SfmPhoto], run: Callable[[list[SfmPhoto]], SfmOutcome]
) -> tuple[SfmOutcome, dict[str, float]]:
    """``run(photos)`` (SfM), then again without the photos whose pose disagrees with the masks, until every
    pose agrees. Returns the outcome (the left-out photos among its ``missing``) and {left-out photo:
    agreement}. Raises ``PoseCheckError`` when poses still disagree after ``AGREEMENT_ROUNDS`` reruns."""
    from go_core.scene.auto_mask import VOTE_MIN_VIEWS

    out, left_out = run(photos), {}
    if any(p.mask is None for p in photos):
        return out, left_out
    for round_ in range(AGREEMENT_ROUNDS + 1):
        posed = [p for p in photos if p.name in out.cameras]
        if len(posed) < VOTE_MIN_VIEWS:
            break
        names = [p.name for p in posed]
        bad = disagreeing(names, [p.mask for p in posed], [out.cameras[n] for n in names])
        if not bad:
            break
        if round_ == AGREEMENT_ROUNDS:
            raise PoseCheckError(
                f"the poses of {', '.join(sorted(bad))} disagree with their masks after {round_} reruns of "
                "SfM without the photos that disagreed"
            )
        left_out.update(bad)
        out = run([p for p in photos if p.name not in left_out])
    order = {p.name: k for k, p in enumerate(photos)}
    out.missing = sorted(set(out.missing) | set(left_out), key=order.__getitem__)
    return out, left_out
