"""Incremental SfM (pycolmap) on every photo of a capture, at a reduced feature resolution.

* Features: COLMAP SIFT (``sift``) or DISK + LightGlue (``disk``, ``go_core.features``), optionally only
  inside each photo's object mask (dilated): a turntable capture has a background that is static relative
  to the camera, and only object features can pose it.
* Pairs: every pair up to ``exhaustive_max`` photos; beyond, a sequential window in file order plus pairs
  at power-of-two distances (COLMAP's quadratic overlap) and the wrap-around of the first and last photos
  (a walk around an object ends where it began), so matching grows as n·log n, not n².
* Cameras: one SIMPLE_RADIAL camera per camera group (photos of one size from one camera model and focal
  length), its focal length seeded from EXIF when known (``has_prior_focal_length``).
* COLMAP logs through glog onto the process's stderr: ``native_stderr_to`` sends the file descriptor into a
  log file during the calls, so that the terminal keeps the pipeline's own lines.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from go_core.camera import Camera
from go_core.errors import PoseCheckError
from go_core.io.images import to_uint8
from go_core.poses.matching import ESTIMATE_MIN_CONFIDENCE, MATCHERS, PEAK_THRESHOLD

CAMERA_MODEL = "SIMPLE_RADIAL"


@dataclass(frozen=True)
class SfmSettings:
    """How SfM runs on a photo set (the ``scene`` step's ``sfm_*`` params)."""

    matcher: str  # sift | disk
    max_features: int
    window: int  # sequential pairs: each photo with the next ``window``
    exhaustive_max: int = 40  # every pair up to this many photos
    mask_dilate_px: int = 8  # features this far outside the mask still count (silhouette edges)
    num_threads: int = 1  # the mapper's; 1: COLMAP's poses repeat exactly
    extraction_workers: int = 1  # SIFT on photo subsets at once, one thread each: identical features
    matching_threads: int = 1  # SIFT matching + verification, per pair: identical at any count
    # COLMAP 4's registration from 2D-2D matches when a photo sees too few 3D points: off. On a 66-photo
    # turntable it once posed 5 front views 56-70 deg off (the rest then built on them) with every check
    # passed; left off, the same database gives bit-identical poses (docs/photos.md, "Repeatability")
    structure_less_fallback: bool = False
    seed: int = 0


@dataclass
class SfmPhoto:
    """One photo as SfM sees it: pixels at the feature size, optional mask, camera group, focal prior."""

    name: str
    image: np.ndarray  # float32 [H, W, 3]
    mask: np.ndarray | None = None
    group: int = 0  # photos of one group share intrinsics
    focal_px: float | None = None  # EXIF focal length in pixels of ``image`` (None: unknown)


@dataclass
class SfmOutcome:
    """Registered cameras (COLMAP frame, at the feature resolution) and the evidence behind them."""

    cameras: dict[str, Camera]
    radial_k1: dict[str, float]  # SIMPLE_RADIAL k1 per registered photo (normalised coordinates)
    missing: list[str]
    mean_reprojection_px: float
    reprojection_px: dict[str, float]  # mean reprojection error of each registered photo's points
    observations: dict[str, int]  # 3D points each registered photo observes
    num_points: int
    num_pairs: int  # pairs matched
    num_verified_pairs: int  # pairs with geometrically verified matches
    masked: bool  # features only inside the masks
    other_models: list[list[str]] = field(default_factory=list)  # photos of other, smaller reconstructions


def match_pairs(n: int, window: int, exhaustive_max: int) -> list[tuple[int, int]]:
    """Index pairs (i < j) to match among ``n`` photos in capture order (see the module docstring)."""
    if n <= exhaustive_max:
        return [(i, j) for i in range(n) for j in range(i + 1, n)]
    pairs = set()
    for i in range(n):
        for d in range(1, window + 1):
            pairs.add((i, (i + d) % n))
        d = 2 * window
        while d < n:
            pairs.add((i, (i + d) % n))
            d *= 2
    return sorted({(min(a, b), max(a, b)) for a, b in pairs if a != b})


@contextlib.contextmanager
def native_stderr_to(path: Path) -> Iterator[None]:
    """Send file descriptor 2 (where COLMAP's glog writes) into ``path`` inside the block."""
    import sys

    sys.stderr.flush()
    saved = os.dup(2)
    with open(path, "ab") as f:
        os.dup2(f.fileno(), 2)
    try:
        yield
    finally:
        sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)


def _write_inputs(photos: list[SfmPhoto], work: Path, use_masks: bool, dilate_px: int) -> list[str]:
    import cv2

    (work / "images").mkdir()
    (work / "masks").mkdir()
    names = []
    for i, p in enumerate(photos):
        name = f"{i:05d}.png"
        cv2.imwrite(str(work / "images" / name), cv2.cvtColor(to_uint8(p.image), cv2.COLOR_RGB2BGR))
        if use_masks:
            m = (np.asarray(p.mask) > 0.5).astype(np.uint8) * 255
            if dilate_px > 0:
                m = cv2.dilate(m, np.ones((2 * dilate_px + 1,) * 2, np.uint8))
            cv2.imwrite(str(work / "masks" / f"{name}.png"), m)
        names.append(name)
    return names


def _add_cameras(db, photos: list[SfmPhoto]) -> dict[int, int]:
    """One camera per group (SIMPLE_RADIAL, EXIF focal as a prior when known); {group: camera_id}."""
    import pycolmap

    ids = {}
    for g in sorted({p.group for p in photos}):
        first = next(p for p in photos if p.group == g)
        h, w = first.image.shape[:2]
        focal = first.focal_px if first.focal_px else 1.2 * max(w, h)  # COLMAP's default factor
        cam = pycolmap.Camera.create_from_model_name(0, CAMERA_MODEL, float(focal), int(w), int(h))
        cam.has_prior_focal_length = first.focal_px is not None
        ids[g] = db.write_camera(cam)
    return ids


def _extract(photos, work, names, use_masks, settings, advance) -> None:
    """Features of every photo, per camera group and in chunks (one progress tick per photo)."""
    import pycolmap

    db_path = work / "database.db"
    db = pycolmap.Database.open(db_path)
    try:
        camera_ids = _add_cameras(db, photos)
    finally:
        db.close()
    if settings.matcher == "disk":
        _extract_disk(photos, work, names, use_masks, settings, camera_ids, advance)
        return
    _import_images(photos, work, names, camera_ids)
    workers = max(1, min(settings.extraction_workers, len(photos)))
    parts = [list(range(k, len(photos), workers)) for k in range(workers)]
    dbs = [work / f"features_{k}.db" for k in range(len(parts))]
    for db_k in dbs:
        shutil.copyfile(db_path, db_k)
    lock = threading.Lock()

    def tick(k: int) -> None:
        with lock:
            advance(k)

    def extract(k: int) -> None:
        _extract_sift(dbs[k], work, [names[i] for i in parts[k]], use_masks, settings, tick)

    with ThreadPoolExecutor(len(parts)) as pool:  # pycolmap releases the GIL while it extracts
        list(pool.map(extract, range(len(parts))))
    _merge_features(db_path, dbs, [[names[i] for i in part] for part in parts])


def _import_images(photos, work, names, camera_ids) -> None:
    """The photos into the database, per camera group in photo order (their image ids)."""
    import pycolmap

    for g, cam_id in camera_ids.items():
        reader = pycolmap.ImageReaderOptions()
        reader.existing_camera_id = cam_id
        group = [names[i] for i, p in enumerate(photos) if p.group == g]
        pycolmap.import_images(
            work / "database.db",
            work / "images",
            pycolmap.CameraMode.SINGLE,
            image_names=group,
            options=reader,
        )


def _extract_sift(db_path, work, names, use_masks, settings, advance) -> None:
    """COLMAP's SIFT on ``names`` (already in ``db_path``) on one thread, in chunks (one tick per photo)."""
    import pycolmap

    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = 1  # COLMAP's own extraction threads change the features (tests/test_photos.py)
    extraction.use_gpu = False
    extraction.sift.max_num_features = settings.max_features
    extraction.sift.peak_threshold = PEAK_THRESHOLD
    reader = pycolmap.ImageReaderOptions()
    if use_masks:
        reader.mask_path = str(work / "masks")
    chunk = 8
    for start in range(0, len(names), chunk):
        part = names[start : start + chunk]
        pycolmap.extract_features(
            db_path,
            work / "images",
            image_names=part,
            camera_mode=pycolmap.CameraMode.SINGLE,
            reader_options=reader,
            extraction_options=extraction,
            device=pycolmap.Device.cpu,
        )
        advance(len(part))


def _merge_features(db_path, dbs, names) -> None:
    """Keypoints and descriptors of each worker's photos from its database into ``db_path``."""
    import pycolmap

    db = pycolmap.Database.open(db_path)
    try:
        ids = {img.name: img.image_id for img in db.read_all_images()}
        for db_k, part in zip(dbs, names, strict=True):
            src = pycolmap.Database.open(db_k)
            try:
                for name in part:
                    db.write_keypoints(ids[name], src.read_keypoints(ids[name]))
                    db.write_descriptors(ids[name], src.read_descriptors(ids[name]))
            finally:
                src.close()
            Path(db_k).unlink()
    finally:
        db.close()


def _extract_disk(photos, work, names, use_masks, settings, camera_ids, advance) -> None:
    """DISK keypoints into the database; descriptors are kept in ``work/disk.npz`` for LightGlue."""
    import pycolmap
    import torch

    from go_core.features.weights import load_disk
    from go_core.poses.matching import _torch_threads, disk_features

    db_path = work / "database.db"
    _import_images(photos, work, names, camera_ids)
    disk = load_disk()
    db = pycolmap.Database.open(db_path)
    store = {}
    try:
        ids = {img.name: img.image_id for img in db.read_all_images()}
        with torch.no_grad(), _torch_threads(1):  # torch may sum in another order at other counts
            for i, p in enumerate(photos):
                ((f, size),) = disk_features(
                    disk, [p], min(settings.max_features, 2048), settings.mask_dilate_px, use_masks
                )
                db.write_keypoints(ids[names[i]], (f.xy_subpixel.numpy() + 0.5).astype(np.float32))
                store[f"{i}_xy"] = f.xy.numpy()
                store[f"{i}_desc"] = f.descriptors.numpy()
                store[f"{i}_size"] = size.numpy()
                advance(1)
    finally:
        db.close()
    np.savez(work / "disk.npz", **store)


def _match(work, names, pairs, settings, advance) -> None:
    """Match ``pairs`` (chunks of pairs, one progress tick per pair) and verify them geometrically."""
    import pycolmap

    from go_core.poses.matching import _verification

    db_path = work / "database.db"
    if settings.matcher == "disk":
        _match_disk(work, names, pairs, settings, advance)
        pairs_path = work / "pairs.txt"
        pairs_path.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in pairs))
        pycolmap.verify_matches(db_path, pairs_path, options=_verification(settings.seed))
        return
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = settings.matching_threads
    matching.use_gpu = False
    chunk = 64
    for start in range(0, len(pairs), chunk):
        part = pairs[start : start + chunk]
        pairs_path = work / "pairs.txt"
        pairs_path.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in part))
        pairing = pycolmap.ImportedPairingOptions()
        pairing.match_list_path = pairs_path
        pycolmap.match_image_pairs(
            db_path,
            matching_options=matching,
            pairing_options=pairing,
            verification_options=_verification(settings.seed),
            device=pycolmap.Device.cpu,
        )
        advance(len(part))


def _match_disk(work, names, pairs, settings, advance) -> None:
    """LightGlue matches of ``pairs`` (confidence above ESTIMATE_MIN_CONFIDENCE) into the database."""
    import pycolmap
    import torch

    from go_core.features.weights import load_lightglue
    from go_core.poses.matching import _torch_threads

    glue = load_lightglue()
    store = np.load(work / "disk.npz")
    db = pycolmap.Database.open(work / "database.db")
    try:
        ids = {img.name: img.image_id for img in db.read_all_images()}

        def feats(i):
            return (torch.from_numpy(store[f"{i}_{k}"]) for k in ("xy", "desc", "size"))

        with torch.no_grad(), _torch_threads(1):  # torch may sum in another order at other counts
            for i, j in pairs:
                xi, di, si = feats(i)
                xj, dj, sj = feats(j)
                m, confidence = glue(xi, di, si, xj, dj, sj)
                m = m[confidence > ESTIMATE_MIN_CONFIDENCE]
                if len(m):
                    db.write_matches(ids[names[i]], ids[names[j]], m.numpy().astype(np.uint32))
                advance(1)
    finally:
        db.close()


def _per_image_errors(rec) -> tuple[dict[int, float], dict[int, int]]:
    """{image_id: mean reprojection error of its observations}, {image_id: observed 3D points}."""
    errors, counts = {}, {}
    for image_id, image in rec.images.items():
        if not image.has_pose:
            continue
        cam = rec.cameras[image.camera_id]
        cam_from_world = image.cam_from_world()
        obs = [p for p in image.points2D if p.has_point3D()]
        if not obs:
            errors[image_id], counts[image_id] = float("inf"), 0
            continue
        xyz = np.stack([rec.points3D[p.point3D_id].xyz for p in obs])
        xy = np.stack([p.xy for p in obs])
        local = xyz @ np.asarray(cam_from_world.rotation.matrix()).T + np.asarray(cam_from_world.translation)
        proj = np.asarray(cam.img_from_cam(local))
        errors[image_id] = float(np.linalg.norm(proj[:, :2] - xy, axis=1).mean())
        counts[image_id] = len(obs)
    return errors, counts


def _outcome(rec, photos, names, pairs, verified, masked) -> SfmOutcome:
    """The registered cameras of ``rec`` as go_core cameras (pinhole K; k1 kept beside)."""
    errors, counts = _per_image_errors(rec)
    index = {n: i for i, n in enumerate(names)}
    cameras, k1, reproj, obs = {}, {}, {}, {}
    for image_id, image in sorted(rec.images.items(), key=lambda kv: index[kv[1].name]):
        if not image.has_pose:
            continue
        p = photos[index[image.name]]
        cam = rec.cameras[image.camera_id]
        f, cx, cy, radial = (float(x) for x in cam.params[:4])
        w2c = np.eye(4)
        w2c[:3] = image.cam_from_world().matrix()
        cameras[p.name] = Camera.from_intrinsics(p.name, cam.width, cam.height, f, f, cx, cy, w2c)
        k1[p.name] = radial
        reproj[p.name] = errors[image_id]
        obs[p.name] = counts[image_id]
    missing = [p.name for p in photos if p.name not in cameras]
    return SfmOutcome(
        cameras,
        k1,
        missing,
        float(rec.compute_mean_reprojection_error()),
        reproj,
        obs,
        int(rec.num_points3D()),
        len(pairs),
        verified,
        masked,
    )


def _verified_pairs(db_path: Path) -> int:
    import pycolmap

    db = pycolmap.Database.open(db_path)
    try:
        return int(db.num_verified_image_pairs())
    finally:
        db.close()


def _at_most(advance: Callable[[int], None], total: int) -> Callable[[int], None]:
    """``advance`` that stops at ``total``: COLMAP calls back again for each further model it starts (a
    second initial pair, photos registered twice), which would count past the number of photos."""
    done = 0

    def step(k: int) -> None:
        nonlocal done
        k = min(k, total - done)
        if k > 0:
            done += k
            advance(k)

    return step


def mapper_options(settings: SfmSettings):
    """COLMAP's incremental mapper options for ``settings``: its threads, its seed, the principal point
    fixed, the structure-less fallback as set (``SfmSettings.structure_less_fallback``)."""
    import pycolmap

    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = settings.num_threads
    options.random_seed = settings.seed
    options.ba_refine_principal_point = False
    if hasattr(options, "structure_less_registration_fallback"):  # older COLMAPs have none
        options.structure_less_registration_fallback = settings.structure_less_fallback
    return options


def run_sfm(
    photos: list[SfmPhoto],
    settings: SfmSettings,
    *,
    use_masks: bool,
    progress: Callable[[str, int], Callable[[int], None]] | None = None,
    log_path: Path | None = None,
    workdir: Path | None = None,
) -> SfmOutcome:
    """SfM on ``photos`` (module docstring). ``progress(label, total)`` returns an ``advance(k)`` callable
    (one bar per stage: features, pairs, photos registered); COLMAP's log lines go to ``log_path``.
    Keeps the reconstruction with the most registered photos. Raises ``PoseCheckError`` when nothing can be
    reconstructed."""
    import pycolmap

    if settings.matcher not in MATCHERS:
        raise PoseCheckError(f"unknown matcher {settings.matcher!r}; choose one of {', '.join(MATCHERS)}")
    use_masks = use_masks and all(p.mask is not None for p in photos)
    progress = progress or (lambda label, total: lambda k: None)
    pairs = match_pairs(len(photos), settings.window, settings.exhaustive_max)
    with tempfile.TemporaryDirectory(prefix="go-photos-sfm-", dir=workdir) as tmp:
        work = Path(tmp)
        log = Path(log_path) if log_path is not None else work / "colmap.log"
        with native_stderr_to(log):
            names = _write_inputs(photos, work, use_masks, settings.mask_dilate_px)
            _extract(photos, work, names, use_masks, settings, progress("features", len(photos)))
            _match(work, names, pairs, settings, progress("pairs matched", len(pairs)))
            verified = _verified_pairs(work / "database.db")
            options = mapper_options(settings)
            advance = _at_most(progress("photos registered", len(photos)), len(photos))
            (work / "sparse").mkdir()
            recs = pycolmap.incremental_mapping(
                work / "database.db",
                work / "images",
                work / "sparse",
                options=options,
                initial_image_pair_callback=lambda: advance(2),
                next_image_callback=lambda: advance(1),
            )
        if not recs:
            where = " inside the masks" if use_masks else ""
            raise PoseCheckError(
                f"no reconstruction: {verified} of {len(pairs)} photo pairs have verified feature matches"
                f"{where}, too few to start one"
            )
        ranked = sorted(recs.values(), key=lambda r: -r.num_reg_images())
        out = _outcome(ranked[0], photos, names, pairs, verified, use_masks)
        index = {n: p.name for n, p in zip(names, photos, strict=True)}
        for rec in ranked[1:]:
            out.other_models.append(sorted(index[im.name] for im in rec.images.values() if im.has_pose))
        return out
