"""Poses for views that have none: incremental SfM (go_core.poses.sfm.reconstruct), then every check of
go_core.poses.verify on the result. One call shared by `go-pipeline poses --estimate` and the ``scene``
step's ``poses: estimate`` (the COLMAP-free profile): a result that may be wrong is refused, with the views
and the reasons, never handed on."""

from __future__ import annotations

from dataclasses import dataclass

from go_core.poses import sfm as pose_sfm
from go_core.poses.matching import DEFAULT_MATCHER
from go_core.poses.sfm import SfmResult
from go_core.poses.verify import PoseVerdict, verify_poses


@dataclass
class PoseEstimate:
    sfm: SfmResult
    registered: list[str]  # view names, in input order
    missing: list[str]
    verdict: PoseVerdict  # problems: why the estimate must not be used (empty: usable)

    @property
    def usable(self) -> bool:
        return not self.verdict.problems


def estimate_poses(
    views,
    *,
    matcher: str = DEFAULT_MATCHER,
    num_threads: int = 2,
    seed: int = 0,
    allow_unregistered: bool = False,
) -> PoseEstimate:
    """SfM on ``views`` (objects with ``name``, ``image`` and optional ``mask``) and the verification of its
    cameras. Raises ``PoseCheckError`` when nothing can be reconstructed; views that could not be registered
    are a problem unless ``allow_unregistered``."""
    sfm = pose_sfm.reconstruct(views, num_threads=num_threads, matcher=matcher, seed=seed)
    registered = [v for v in views if v.name in sfm.cameras]
    missing = [v.name for v in views if v.name not in sfm.cameras]
    masks = [v.mask for v in registered] if all(v.mask is not None for v in registered) else None
    verdict = verify_poses(
        [sfm.cameras[v.name] for v in registered],
        masks,
        mean_reprojection_px=sfm.mean_reprojection_px,
        observations=sfm.observations,
    )
    if missing and not allow_unregistered:
        verdict.problems.insert(
            0,
            f"{len(missing)} of {len(views)} images could not be registered: {', '.join(missing)} "
            "(too few matches with the others)",
        )
    return PoseEstimate(sfm, [v.name for v in registered], missing, verdict)
