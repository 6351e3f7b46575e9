"""The ``scene`` step: read the scene folder, validate it, choose the training views, downscale, and write
the artifact every downstream step reads (``go_core.scene.artifact``: ``scene.json`` + ``views.npz``, and
``mesh_world.npz`` when the folder carries a ground-truth mesh: eval's geometry metrics)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from go_core import artifacts as art
from go_core.errors import SceneError
from go_core.scene.artifact import Ingest
from go_core.scene.loader import load_scene

if TYPE_CHECKING:
    from go_pipeline.steps.params import SceneParams


def _estimate_training_poses(scene, params: SceneParams, seed: int, folder: Path) -> None:
    """Replace the training cameras by SfM's (go_core.poses.estimate), or raise one SceneError naming the
    views and why: a pose that may be wrong never reaches the hull."""
    from dataclasses import replace

    from go_core.camera import Camera
    from go_core.errors import PoseCheckError
    from go_core.poses.estimate import estimate_poses

    names = ", ".join(v.name for v in scene.train)
    try:  # one thread: COLMAP's results repeat exactly only then (the step is deterministic)
        est = estimate_poses(scene.train, matcher=params.pose_matcher, num_threads=1, seed=seed)
    except PoseCheckError as exc:
        raise SceneError(
            f"scene.poses=estimate: no poses for the training views ({names}): {exc}", folder
        ) from None
    if not est.usable:
        problems = "; ".join(est.verdict.problems)
        raise SceneError(
            f"scene.poses=estimate: the estimated training poses ({names}) are refused: {problems}",
            folder,
        )
    for i, view in enumerate(scene.train):
        cam = est.sfm.cameras[view.name]
        scene.train[i] = replace(
            view, camera=Camera(view.name, cam.width, cam.height, cam.K, cam.world_to_cam)
        )


PHOTO_VIEWS = 4  # training views chosen from a photo folder when scene.views is 0 (the paper's setting)


def _photo_scene(ctx, folder: Path, params: SceneParams):
    """A folder of photos without poses: masks, SfM on every photo, the training views (go_core.photos)."""
    import torch

    from go_core.io.atomic import atomic_write_json
    from go_core.photos.masks import photo_masker
    from go_core.photos.scene import PhotoSettings, read_photo_scene
    from go_core.photos.sfm import SfmSettings

    # the masks, SIFT extraction (one photo subset per thread) and matching use the step's threads:
    # bit-identical at 1 and 2 (tests/test_photos.py); the mapper runs on one: its bundle adjustments at 2
    # threads, like COLMAP's own extraction threads, moved the poses by ~1e-3 on photos/ethiopian_head
    threads = torch.get_num_threads()
    masker, method = photo_masker(params.photo_masks, threads=threads)
    sfm = SfmSettings(
        matcher=params.pose_matcher,
        max_features=params.sfm_features,
        window=params.sfm_window,
        extraction_workers=threads,
        matching_threads=threads,
        seed=int(ctx.seed),
    )
    settings = PhotoSettings(
        views=params.views or PHOTO_VIEWS,
        photo_size=params.photo_size,
        sfm_size=params.sfm_size,
        min_registered=params.min_registered,
        sfm=sfm,
    )
    bars = []

    def progress(label: str, total: int):
        if bars:
            bars[-1].close()
        bars.append(ctx.progress(total, label))
        return bars[-1].advance

    log_path = ctx.out_dir / "colmap.log"  # read into the run log and removed below
    try:
        scene, record = read_photo_scene(folder, settings, masker, progress=progress, log_path=log_path)
    finally:
        if bars:
            bars[-1].close()
        if log_path.is_file():
            for line in log_path.read_text(errors="replace").splitlines():
                ctx.log.debug("colmap: %s", line)
            log_path.unlink()
    record["masks"] = method if record["masks"] == "auto" else record["masks"]
    atomic_write_json(art.SCENE_PHOTOS.path(ctx.out_dir), record)
    sfm_rec = record["sfm"]
    ctx.log.info(
        "photos: %d of %d posed (%s, %s, mean reprojection %.2f px); training views %s",
        sfm_rec["registered"],
        record["photos"],
        sfm_rec["matcher"],
        sfm_rec["features"],
        sfm_rec["mean_reprojection_px"],
        ", ".join(record["views"]["train"]),
    )
    if sfm_rec["not_registered"]:
        ctx.log.warning("photos not posed (left out): %s", ", ".join(sfm_rec["not_registered"]))
    ctx.record(photos=record["photos"], registered=sfm_rec["registered"], masks=record["masks"])
    return scene, record


def _copy_ground_truth_mesh(folder: Path, out_dir: Path) -> bool:
    """Copy the folder's ground-truth ``mesh_world.npz`` (evaluation only: eval's geometry metrics), after
    checking it; False when the folder has none."""
    src = art.GT_MESH.path(folder)
    if not src.is_file():
        return False
    from go_core.io.atomic import atomic_write_bytes
    from go_core.mesh.files import read_mesh_npz

    read_mesh_npz(src)  # one clear error for a malformed file
    atomic_write_bytes(art.GT_MESH.path(out_dir), src.read_bytes())
    return True


def run(ctx, inputs: dict[str, Path], params: SceneParams) -> None:
    """``inputs["folder"]`` is the raw scene folder (``folder: "@scene"`` in pipeline.yaml)."""
    from go_core.photos.folder import is_photo_folder

    views, max_size = params.views, params.max_size
    given, how = None, "given"
    if is_photo_folder(inputs["folder"]):  # train and test poses from one SfM: "given" for eval
        scene, _ = _photo_scene(ctx, inputs["folder"], params)
        views, max_size = len(scene.train), params.photo_size
    else:
        scene = load_scene(inputs["folder"], views=views, max_size=max_size)
    if params.poses == "estimate" and scene.format != "photos":
        given = {v.name: v.camera.world_to_cam for v in scene.train}
        _estimate_training_poses(scene, params, int(ctx.seed), inputs["folder"])
        how = f"estimated ({params.pose_matcher}, verified)"
        ctx.log.info("scene: training poses %s", how)
    elif params.poses == "initial" and scene.format != "photos":
        from dataclasses import replace

        from go_core.scene.initial_poses import INITIAL_POSES_FILE, read_initial_poses

        given = {v.name: v.camera.world_to_cam for v in scene.train}
        cameras = read_initial_poses(inputs["folder"], scene.train_cameras)
        scene.train[:] = [replace(v, camera=c) for v, c in zip(scene.train, cameras, strict=True)]
        how = f"initial ({INITIAL_POSES_FILE})"
        ctx.log.info("scene: training poses from %s", INITIAL_POSES_FILE)
    ingest = Ingest(views_requested=views, max_size=max_size, given_poses=given, poses=how)
    manifest = art.write_scene(ctx.out_dir, scene, ingest)
    has_truth = _copy_ground_truth_mesh(Path(inputs["folder"]), ctx.out_dir)
    from go_pipeline.manifest import schema_problems

    problems = schema_problems("scene_manifest", manifest)
    if problems:  # a bug, not bad input: the artifact must never be marked complete
        path = art.SCENE_INFO.path(ctx.out_dir)
        raise SceneError(f"does not match scene_manifest.schema.json: {problems[0]}", path)
    if 0 < max_size < scene.original_max_side:
        setting, keep = (
            ("scene.photo_size", "--set scene.photo_size=800 trains on larger images")
            if scene.format == "photos"
            else ("scene.max_size", "--set scene.max_size=0 keeps the full resolution")
        )
        ctx.log.warning(
            "images up to %d px on their longest side were downscaled to %d px (%s; %s: slower, and memory "
            "grows with the pixels)",
            scene.original_max_side,
            max_size,
            setting,
            keep,
        )
    sizes = sorted({f"{c['width']}x{c['height']}" for c in manifest["train"] + manifest["test"]})
    ctx.log.info(
        "scene: %s, %d train + %d test views, %s (%s)",
        scene.format,
        len(scene.train),
        len(scene.test),
        ", ".join(sizes),
        scene.split_source,
    )
    ctx.record(
        format=scene.format,
        train_views=[v.name for v in scene.train],
        test_views=len(scene.test),
        resolutions=sizes,
        split_source=scene.split_source,
        downscaled_from=scene.original_max_side if 0 < max_size < scene.original_max_side else None,
        masks=sum(v.mask is not None for v in scene.train + scene.test),
        ground_truth_mesh=has_truth,
    )
