"""A folder of photos without poses read into a posed ``Scene``: masks, SfM on every photo, N training views.

1. Photos are read upright (EXIF) at ``photo_size`` (``go_core.photos.folder``), and again at ``sfm_size``
   for SfM when that is larger; unreadable photos, too few photos and duplicates are errors naming the
   files.
2. Masks: a photo's own alpha when every photo has one, else ``masker`` (the auto masks) on every photo,
   both at ``MASK_SIZE`` whatever ``photo_size`` is (SfM restricts its features to them, so the poses, the
   registered photos and the training views do not depend on the training size); scaled to ``photo_size``.
3. SfM (``go_core.photos.sfm``) at ``sfm_size``: first with features inside the masks (works for a
   turntable, whose background is static relative to the camera, and for a walk around a static object),
   then, when that result fails a check, on whole images (a static object on a textured background). The
   first result that passes every check is kept; checks: at least ``min_registered`` of the photos
   registered, viewing directions spanning at least 15°, mean reprojection error, points per photo
   (``go_core.poses.verify``), and the masks of the chosen training views agreeing with their poses.
4. The frame is normalised and ``views`` training views spread around the object are chosen
   (``go_core.photos.views``); every other registered photo is a test view. Images and masks are
   undistorted (SIMPLE_RADIAL k1) onto pinhole cameras at ``photo_size``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from go_core.camera import Camera
from go_core.errors import PoseCheckError, SceneError
from go_core.photos.agreement import sfm_agreeing
from go_core.photos.folder import (
    MIN_PHOTOS,
    PhotoFile,
    camera_groups,
    duplicate_pairs,
    photo_dir,
    photo_files,
    read_photo,
    scan_photo,
)
from go_core.photos.sfm import SfmOutcome, SfmPhoto, SfmSettings, run_sfm
from go_core.photos.views import choose_spread_views, normalising_similarity
from go_core.scene.common import Distortion, Problems, _undistort
from go_core.scene.types import Scene, View

DOCS = "docs/photos.md"
MASK_SIZE = 512  # long side the masks are made at (u2netp sees 320² crops of it), whatever photo_size is


@dataclass(frozen=True)
class PhotoSettings:
    """The ``scene`` step's photo-folder params (steps/params.py SceneParams holds the defaults)."""

    views: int  # training views to choose
    photo_size: int  # long side of the training and test images
    sfm_size: int  # long side of the images SfM extracts features from
    min_registered: float  # fraction of the photos SfM must pose
    sfm: SfmSettings


Progress = Callable[[str, int], Callable[[int], None]]


def _quiet_progress(label: str, total: int) -> Callable[[int], None]:
    return lambda k: None


def scan_photo_folder(root: Path, views: int, problems: Problems) -> list[PhotoFile]:
    """Header facts of every photo of the folder; too few photos and unreadable headers are problems."""
    folder = photo_dir(root)
    if folder is None:
        problems.add("no photos found (JPEG, PNG, TIFF, WebP, HEIC) in the folder or its images/", root)
        return []
    files = [p for p in (scan_photo(f, problems) for f in photo_files(folder)) if p is not None]
    need = max(MIN_PHOTOS, views + 1)
    if len(photo_files(folder)) < need:
        problems.add(
            f"found {len(photo_files(folder))} photos; posing them needs at least {need} taken around the "
            f"object (20-60 give the best poses: {DOCS})",
            folder,
        )
    return files


def _read_all(files: list[PhotoFile], long_side: int, progress: Progress) -> tuple[list, list]:
    advance = progress("photos read", len(files))
    images, alphas = [], []
    for f in files:
        rgb, alpha = read_photo(f, long_side)  # ImageReadError names a corrupt or truncated file
        images.append(rgb)
        alphas.append(alpha)
        advance(1)
    dup = duplicate_pairs([f.name for f in files], images)
    if dup:
        a, b = dup[0]
        more = f" (and {len(dup) - 1} more pairs)" if len(dup) > 1 else ""
        raise SceneError(
            f"photos {a} and {b} show the same picture{more}: remove the copies", files[0].path.parent
        )
    return images, alphas


def photo_masks(
    files: list[PhotoFile],
    masker: Callable[[np.ndarray], np.ndarray],
    progress: Progress | None = None,
    read: tuple[list, list] | None = None,
) -> tuple[list[np.ndarray], str]:
    """The masks the scene step makes, at ``MASK_SIZE`` whatever ``photo_size`` is, and where they came
    from: every photo's own alpha channel when all have one ("alpha"), else ``masker`` on each photo
    ("auto"). ``read``: the photos' (images, alphas) when already read at ``MASK_SIZE``."""
    progress = progress or _quiet_progress
    if read is None:
        read = tuple(zip(*(read_photo(f, MASK_SIZE) for f in files), strict=True))
    images, alphas = read
    if all(a is not None for a in alphas):
        return [np.asarray(a, np.float32) for a in alphas], "alpha"
    advance = progress("masks", len(images))
    out = []
    for img in images:
        out.append(np.asarray(masker(img), np.float32))
        advance(1)
    return out, "auto"


def _voted_masks(views: dict[int, View]) -> dict[int, View]:
    """The auto masks made consistent through the SfM poses (``hull_vote_masks``: what one photo's mask
    wrongly takes in, e.g. a turntable disc, is carved away by the photos that leave it out; issue 32's
    screening: mean IoU 0.825 -> 0.982 on ethiopian_head); unchanged below ``VOTE_MIN_VIEWS`` photos or
    when the masks agree on no region."""
    from dataclasses import replace

    from go_core.errors import EmptyHullError
    from go_core.scene.auto_mask import VOTE_MIN_VIEWS, hull_vote_masks

    keys = list(views)
    if len(keys) < VOTE_MIN_VIEWS:
        return views
    try:
        voted = hull_vote_masks([views[k].mask for k in keys], [views[k].camera for k in keys])
    except EmptyHullError:
        return views
    return {k: replace(views[k], mask=soft_edges(views[k].mask, m)) for k, m in zip(keys, voted, strict=True)}


def soft_edges(soft: np.ndarray, binary: np.ndarray) -> np.ndarray:
    """``binary`` (a voted {0, 1} mask) with the anti-aliased edge of ``soft`` (the same mask before the
    vote, area-scaled to the photo size): 1 inside ``binary`` shrunk by one pixel, ``soft`` in the band of
    a pixel on each side of its edge, 0 beyond (holes the vote filled stay filled). A
    binary edge is up to a pixel off the photo's own anti-aliased edge, which at 256 px cost 0.42 dB of
    test PSNR on photos/ethiopian_head (reference masks scored binarised vs as they are)."""
    import cv2

    b, square = binary.astype(np.uint8), np.ones((3, 3), np.uint8)
    grown, core = cv2.dilate(b, square) > 0, cv2.erode(b, square) > 0
    return np.where(core, 1.0, np.where(grown, np.clip(soft, 0.0, 1.0), 0.0)).astype(np.float32)


def _resize(a: np.ndarray, long_side: int) -> np.ndarray:
    import cv2

    h, w = a.shape[:2]
    if max(h, w) <= long_side:
        return a
    s = long_side / max(h, w)
    return cv2.resize(a, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)


def _resize_to(mask: np.ndarray, shape: tuple[int, int], shrink_by_area: bool = False) -> np.ndarray:
    """``mask`` at exactly ``shape`` (masks are made at ``MASK_SIZE``; SfM and training use other sizes);
    ``shrink_by_area``: a smaller ``shape`` averages the pixels (anti-aliased edges, as the photo's own)."""
    import cv2

    if mask.shape[:2] == tuple(shape):
        return mask
    smaller = shape[0] * shape[1] < mask.shape[0] * mask.shape[1]
    how = cv2.INTER_AREA if shrink_by_area and smaller else cv2.INTER_LINEAR
    return cv2.resize(mask, (shape[1], shape[0]), interpolation=how)


def _sfm_images(
    files: list[PhotoFile], images: list[np.ndarray], settings: PhotoSettings
) -> list[np.ndarray]:
    """The photos as SfM reads them: at ``sfm_size`` when that is larger than ``photo_size`` (read again
    from the files, so that the training images stay one area-filtered resize of the originals)."""
    if settings.sfm_size <= settings.photo_size:
        return images
    return [read_photo(f, settings.sfm_size)[0] for f in files]


def _unposed_message(missing: list[str], total: int, other_models: list[list[str]]) -> str:
    names = ", ".join(missing[:12]) + (f" and {len(missing) - 12} more" if len(missing) > 12 else "")
    if other_models and len(other_models[0]) >= 3:
        return (
            f"the photos form separate groups that share no features ({total - len(missing)} posed together, "
            f"{len(other_models[0])} apart: {', '.join(other_models[0][:8])}): two different objects or "
            "scenes? Keep the photos of one object in the folder"
        )
    return (
        f"{len(missing)} of {total} photos could not be posed: {names}. Take more photos around the object "
        "near them (every 10-15°, the object filling most of the frame, sharp and evenly lit), or remove "
        f"them ({DOCS})"
    )


def _sfm_problems(out: SfmOutcome, total: int, settings: PhotoSettings) -> list[str]:
    """Why an SfM result must not be used (empty: it passes)."""
    from go_core.poses.verify import verify_poses

    problems = []
    if len(out.cameras) < settings.min_registered * total or len(out.cameras) < settings.views + 1:
        problems.append(_unposed_message(out.missing, total, out.other_models))
    verdict = verify_poses(
        list(out.cameras.values()),
        None,
        mean_reprojection_px=out.mean_reprojection_px,
        observations=out.observations,
    )
    return problems + verdict.problems


MAX_VIEW_RETRIES = 4  # training views whose mask disagrees with the others, left out before giving up


def _agreeing_views(views: list[View], n: int, folder: Path) -> tuple:
    """The spread choice of ``n`` views whose masks agree with their poses (visual-hull coverage, as
    ``go_core.poses.verify``): a view whose mask the others' hull covers least is left out and the choice
    repeated, up to ``MAX_VIEW_RETRIES`` times (an auto mask that took in a turntable disc, say). Returns
    (choice, indices left out); one SceneError when no choice agrees."""
    from go_core.poses.verify import MIN_COVERAGE, verify_poses

    cameras = [v.camera for v in views]
    rejected: list[int] = []
    for _ in range(MAX_VIEW_RETRIES + 1):
        choice = choose_spread_views(cameras, n, frozenset(rejected))
        chosen = [views[k] for k in choice.indices]
        verdict = verify_poses([v.camera for v in chosen], [v.mask for v in chosen])
        if not verdict.problems:
            return choice, rejected
        cover = verdict.mask_coverage or {}
        if not cover or min(cover.values()) >= MIN_COVERAGE:
            break  # not a single view's mask: retrying cannot help
        worst = min(cover, key=cover.get)
        rejected.append(next(k for k in choice.indices if views[k].name == worst))
    raise SceneError(
        "the masks of the chosen training views disagree with their SfM poses: "
        + "; ".join(verdict.problems),
        folder,
    )


def pose_photos(
    names: list[str],
    images: list[np.ndarray],
    masks: list[np.ndarray],
    groups: list[int],
    focal_px: list[float | None],
    settings: PhotoSettings,
    progress: Progress,
    log_path: Path | None,
    where: Path,
) -> tuple[SfmOutcome, list[dict]]:
    """SfM with masked features, then on whole images; the first result that passes (module docstring).
    Returns it and a record of every attempt; raises ``SceneError`` with the reasons when none passes."""
    photos = []
    for n, img, m, g, f in zip(names, images, masks, groups, focal_px, strict=True):
        img = _resize(img, settings.sfm_size)
        photos.append(SfmPhoto(n, img, _resize_to(m, img.shape[:2]), g, f))
    attempts, failures = [], []
    for masked in (True, False):
        start = time.perf_counter()
        label = "object features (inside the masks)" if masked else "whole images"
        try:
            sfm = partial(
                run_sfm, settings=settings.sfm, use_masks=masked, progress=progress, log_path=log_path
            )
            out, left_out = sfm_agreeing(photos, sfm)
        except PoseCheckError as exc:
            attempts.append({"masked": masked, "error": str(exc)})
            failures.append(f"{label}: {exc}")
            continue
        problems = _sfm_problems(out, len(photos), settings)
        attempts.append(
            {
                "masked": masked,
                "registered": len(out.cameras),
                "missing": out.missing,
                "mean_reprojection_px": round(out.mean_reprojection_px, 4),
                "verified_pairs": out.num_verified_pairs,
                "pairs": out.num_pairs,
                "problems": problems,
                "left_out_disagreeing_with_masks": left_out,
                "seconds": round(time.perf_counter() - start, 1),
            }
        )
        if not problems:
            return out, attempts
        failures.append(f"{label}: " + "; ".join(problems))
    raise SceneError("the photos could not be posed. " + " | ".join(failures), where)


def _posed_view(name, image, mask, cam: Camera, k1: float, sfm_size: int, source: Path) -> View:
    """The view at the image's size: K scaled from the SfM size, image and mask undistorted (k1)."""
    h, w = image.shape[:2]
    K = cam.K.copy()
    K[0] *= w / cam.width
    K[1] *= h / cam.height
    posed = Camera(name, w, h, K, cam.world_to_cam)
    if abs(k1) > 0:
        import cv2

        d = Distortion(K, np.array([k1, 0.0, 0.0, 0.0]))
        image = _undistort(image, d, cv2.INTER_LINEAR)
        mask = _undistort(mask, d, cv2.INTER_LINEAR)
    return View(
        posed, np.ascontiguousarray(image, np.float32), np.ascontiguousarray(mask, np.float32), source
    )


def read_photo_scene(
    root: str | Path,
    settings: PhotoSettings,
    masker: Callable[[np.ndarray], np.ndarray],
    *,
    progress: Progress | None = None,
    log_path: Path | None = None,
) -> tuple[Scene, dict]:
    """The posed scene of a photo folder (module docstring) and the record of how it was made.
    Raises ``SceneError`` (one line naming the file or folder and the problem) at the first problem."""
    root = Path(root)
    progress = progress or _quiet_progress
    files = scan_photo_folder(root, settings.views, Problems(strict=True))
    images, alphas = _read_all(files, settings.photo_size, progress)
    # at another photo_size the masks read the files again (the duplicate check above already ran on them)
    same = (images, alphas) if settings.photo_size == MASK_SIZE else None
    masks, mask_source = photo_masks(files, masker, progress, same)
    groups = camera_groups(files)
    sfm_images = _sfm_images(files, images, settings)
    focal = [f.focal_px(max(img.shape[:2])) for f, img in zip(files, sfm_images, strict=True)]
    names = [f.name for f in files]
    folder = files[0].path.parent
    out, attempts = pose_photos(names, sfm_images, masks, groups, focal, settings, progress, log_path, folder)
    del sfm_images
    sim = normalising_similarity(list(out.cameras.values()))
    cams = {n: sim.camera(c) for n, c in out.cameras.items()}
    posed = [i for i, n in enumerate(names) if n in cams]
    views = {
        i: _posed_view(
            names[i],
            images[i],
            _resize_to(masks[i], images[i].shape[:2], shrink_by_area=True),
            cams[names[i]],
            out.radial_k1[names[i]],
            settings.sfm_size,
            files[i].path,
        )
        for i in posed
    }
    if mask_source == "auto":
        views = _voted_masks(views)
    choice, rejected = _agreeing_views([views[i] for i in posed], settings.views, folder)
    train_idx = [posed[k] for k in choice.indices]
    train = [views[i] for i in train_idx]
    test = [views[i] for i in posed if i not in train_idx]
    source = (
        f"{len(train)} views spread around the object from {len(posed)} posed photos "
        f"(azimuth gaps {', '.join(f'{g:.0f}' for g in choice.gaps_deg)} deg); test: the other posed photos"
    )
    scene = Scene(root, "photos", train, test, source, max(max(f.width, f.height) for f in files))
    record = {
        "folder": str(folder),
        "photos": len(files),
        "camera_groups": len(set(groups)),
        "exif_focal": sum(f is not None for f in focal),
        "rotated_by_exif": [f.name for f in files if f.orientation != 1],
        "masks": mask_source,
        "sfm": _sfm_record(out, attempts, settings),
        "views": {
            "train": [names[i] for i in train_idx],
            "why": choice.to_dict(),
            "rejected_for_masks": [names[posed[k]] for k in rejected],
        },
    }
    return scene, record


def _sfm_record(out: SfmOutcome, attempts: list, settings: PhotoSettings) -> dict:
    """The scene record's ``sfm`` entry: how the photos were posed, and the checks they passed."""
    return {
        "matcher": settings.sfm.matcher,
        "features": "inside the masks" if out.masked else "whole images",
        "registered": len(out.cameras),
        "not_registered": out.missing,
        "mean_reprojection_px": round(out.mean_reprojection_px, 4),
        "reprojection_px": {k: round(v, 4) for k, v in out.reprojection_px.items()},
        "observations": out.observations,
        "points": out.num_points,
        "pairs": out.num_pairs,
        "verified_pairs": out.num_verified_pairs,
        "attempts": attempts,
        "checks_passed": [
            "registered fraction",
            "rotation spread",
            "reprojection error",
            "points per photo",
            "training masks agree with poses",
        ],
    }


def photo_folder_facts(root: str | Path, views: int, problems: Problems) -> dict:
    """What ``go-pipeline validate`` says about a photo folder without running SfM: the photos, their
    cameras, every unreadable or duplicate photo (to ``problems``), and what a run will do."""
    from go_core.io.images import ImageReadError
    from go_core.photos.sfm import match_pairs

    root = Path(root)
    views = views or 4
    files = scan_photo_folder(root, views, problems)
    images = []
    for f in files:
        try:
            images.append(read_photo(f, 64)[0])
        except ImageReadError as exc:
            problems.extend(exc)
    if len(images) == len(files):
        for a, b in duplicate_pairs([f.name for f in files], images):
            problems.add(f"photos {a} and {b} show the same picture: remove the copies", files[0].path.parent)
    if not files:
        return {}
    groups = camera_groups(files)
    sizes = sorted({f"{f.width}x{f.height}" for f in files})
    return {
        "format": "photos",
        "folder": str(files[0].path.parent),
        "photos": len(files),
        "sizes": sizes,
        "camera_groups": len(set(groups)),
        "exif_focal": sum(f.focal35_mm is not None for f in files),
        "rotated_by_exif": [f.name for f in files if f.orientation != 1],
        "plan": [
            "mask every photo (u2netp when fetched, else GrabCut)",
            f"SfM on all {len(files)} photos ({len(match_pairs(len(files), 6, 40))} pairs), features inside "
            "the masks first, whole images if that fails a check",
            f"choose {views} training views spread around the object; the other posed photos are test views",
            "train and evaluate at scene.photo_size px on the long side",
        ],
    }
