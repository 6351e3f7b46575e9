"""Incremental SfM with pycolmap for views without poses (features and matches from go_core.poses.matching;
go_core.poses.estimate verifies the result before anything uses it)."""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from go_core.camera import Camera
from go_core.errors import PoseCheckError
from go_core.poses.matching import DEFAULT_MATCHER, ESTIMATE_MIN_CONFIDENCE, extract_and_match


@dataclass
class SfmResult:
    """Incremental SfM output: cameras of the registered views in COLMAP's arbitrary frame and scale."""

    cameras: dict  # {view name: Camera}
    mean_reprojection_px: float
    observations: dict  # {view name: 3D points it observes}
    num_points: int
    num_verified_pairs: int


def reconstruct(
    views,
    workdir: Path | None = None,
    num_threads: int = 2,
    max_features: int = 4096,
    seed: int = 0,
    matcher: str = DEFAULT_MATCHER,
) -> SfmResult:
    """Incremental SfM with pycolmap for images without poses (``views``: objects with ``name``, ``image``
    and optional ``mask``). One shared PINHOLE camera is estimated. Keeps the largest reconstruction.
    The learned matcher keeps only matches above ESTIMATE_MIN_CONFIDENCE.
    COLMAP's RANSAC and mapper draw from ``seed``; results repeat exactly only with ``num_threads=1``.
    Raises ``PoseCheckError`` when nothing can be reconstructed, saying why."""
    import pycolmap

    with tempfile.TemporaryDirectory(prefix="go-sfm-", dir=workdir) as tmp:
        work = Path(tmp)
        _, matches = extract_and_match(
            views,
            work,
            max_features,
            num_threads,
            camera_model="PINHOLE",
            matcher=matcher,
            seed=seed,
            min_confidence=ESTIMATE_MIN_CONFIDENCE,
        )
        out = work / "sparse"
        out.mkdir()
        options = pycolmap.IncrementalPipelineOptions()
        options.num_threads = num_threads
        options.random_seed = seed  # the mapper's own PRNG (options, not pycolmap.set_random_seed)
        recs = pycolmap.incremental_mapping(work / "database.db", work / "images", out, options=options)
    if not recs:
        masked = all(getattr(v, "mask", None) is not None for v in views)
        raise PoseCheckError(
            f"no reconstruction: {len(matches)} image pair(s) of {len(views)} images have verified feature "
            f"matches{' inside the masks' if masked else ''}, too few to start one. The views are too far "
            "apart or the object has too little texture: add photos between the views"
        )
    rec = max(recs.values(), key=lambda r: r.num_reg_images())
    cameras, observations = {}, {}
    for image in rec.images.values():
        if not image.has_pose:
            continue
        view = views[int(Path(image.name).stem)]
        cam = image.camera
        fx, fy, cx, cy = (float(x) for x in cam.params[:4])
        w2c = np.eye(4)
        w2c[:3] = image.cam_from_world().matrix()
        cameras[view.name] = Camera.from_intrinsics(view.name, cam.width, cam.height, fx, fy, cx, cy, w2c)
        observations[view.name] = int(image.num_points3D)
    return SfmResult(
        cameras,
        float(rec.compute_mean_reprojection_error()),
        observations,
        int(rec.num_points3D()),
        len(matches),
    )
