"""Feature extraction and matching for the pose code: pycolmap SIFT with its exhaustive matcher, or DISK
keypoints with LightGlue (go_core.features), inside each view's dilated mask (a turntable background cannot
vote), every matched pair verified by COLMAP's two-view geometry (the images only, never the given poses).
Returns keypoints and verified inlier matches per pair for the pose check (go_core.poses.check) and SfM
(go_core.poses.sfm)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from go_core.errors import PoseCheckError
from go_core.io.images import to_uint8

PEAK_THRESHOLD = 0.002  # SIFT DoG peak threshold: below COLMAP's 0.0067 for the smooth objects we scan


def _write_inputs(views, root: Path, dilate_px: int, use_masks: bool = True) -> tuple[list[str], bool]:
    """PNG images (and masks for pycolmap's reader: features only where the mask is > 0) into ``root``."""
    import cv2

    img_dir, mask_dir = root / "images", root / "masks"
    img_dir.mkdir(parents=True)
    mask_dir.mkdir()
    names, have_masks = [], use_masks and all(v.mask is not None for v in views)
    for i, v in enumerate(views):
        name = f"{i:04d}.png"
        rgb = to_uint8(v.image)
        cv2.imwrite(str(img_dir / name), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        if have_masks:
            m = (np.asarray(v.mask) > 0.5).astype(np.uint8) * 255
            if dilate_px > 0:
                m = cv2.dilate(m, np.ones((2 * dilate_px + 1, 2 * dilate_px + 1), np.uint8))
            cv2.imwrite(str(mask_dir / f"{name}.png"), m)  # COLMAP: mask of a.png is a.png.png
        names.append(name)
    return names, have_masks


def _quiet(pycolmap) -> None:
    """COLMAP logs every stage at INFO on stderr; keep warnings and errors only."""
    try:
        pycolmap.logging.minloglevel = max(int(pycolmap.logging.minloglevel), 1)
    except (AttributeError, TypeError, ValueError):
        pass


MATCHERS = ("sift", "disk")  # disk: DISK features + LightGlue (go_core.features)
# with whole-pixel DISK keypoints a correct pair's median epipolar distance exceeded the size-scaled threshold
# (1.08 px against 0.94 px at 160 px on the example scene); the floor stays with the sub-pixel peaks
LEARNED_MIN_THRESHOLD_PX = 1.5
DEFAULT_MATCHER = "sift"
# LightGlue's match confidence floor: its own default for the check, whose verdicts rest on every pair with
# the given poses; 0.9 for estimation, where a wrong pair becomes a wrong camera. Wide-baseline pairs of a
# shiny or symmetric object get tens of wrong matches (median confidence 0.04 against 0.47 for right ones)
# that share the true epipolar lines' direction (turntable: near-horizontal), so COLMAP's two-view
# verification passes them: real/ethiopian_head (12 views) had 53 of 66 verified pairs wrong at 0.1, 0 of
# 10 at 0.9 (docs/evaluation.md)
CHECK_MIN_CONFIDENCE = 0.1
# COLMAP's SIFT matcher threads for the check. With two, the same views once gave 343 and then 344 tracks
# (issue 82). Several matcher threads are the only concurrent work left in the check (extraction runs on one
# thread, RANSAC is seeded): each builds and searches FAISS IVF indexes (k-means, 4 of ~100 lists probed:
# approximate, so a tiny numeric difference can move a match) through the wheel's static OpenBLAS at once.
CHECK_MATCH_THREADS = 1
ESTIMATE_MIN_CONFIDENCE = 0.9


def _verification(seed: int):
    """COLMAP's two-view geometry options with RANSAC drawing from ``seed`` (an option, never the global
    PRNG: pycolmap.set_random_seed would reseed the whole process)."""
    import pycolmap

    options = pycolmap.TwoViewGeometryOptions()
    options.ransac.random_seed = int(seed)
    return options


def _sift_into_database(
    views, work, names, have_masks, max_features, num_threads, peak_threshold, camera_model, seed
):
    """pycolmap SIFT extraction (inside the masks) and exhaustive matching into ``work/database.db``,
    matching on ``num_threads`` threads."""
    import pycolmap

    db_path = work / "database.db"
    reader = pycolmap.ImageReaderOptions()
    if have_masks:
        reader.mask_path = str(work / "masks")
    if camera_model:
        reader.camera_model = camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = 1  # COLMAP's threaded SIFT extraction varies from run to run
    extraction.use_gpu = False
    extraction.sift.max_num_features = max_features
    extraction.sift.peak_threshold = peak_threshold
    pycolmap.extract_features(
        db_path,
        work / "images",
        image_names=names,
        camera_mode=pycolmap.CameraMode.SINGLE if camera_model else pycolmap.CameraMode.PER_IMAGE,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = num_threads
    matching.use_gpu = False
    pycolmap.match_exhaustive(
        db_path,
        matching_options=matching,
        verification_options=_verification(seed),
        device=pycolmap.Device.cpu,
    )


def disk_features(disk, views, max_features: int, dilate_px: int, have_masks: bool = True) -> list:
    """Per view: DISK features (``go_core.features.disk.detect``) inside its mask dilated by ``dilate_px``
    (the whole image without masks), and the image size [w, h] LightGlue normalises keypoints by."""
    import cv2
    import torch

    from go_core.features.disk import detect

    feats = []
    for v in views:
        img = torch.from_numpy(np.ascontiguousarray(np.clip(v.image, 0, 1).transpose(2, 0, 1))).float()
        mask = None
        if have_masks:
            m = (np.asarray(v.mask) > 0.5).astype(np.uint8)
            if dilate_px > 0:
                m = cv2.dilate(m, np.ones((2 * dilate_px + 1, 2 * dilate_px + 1), np.uint8))
            mask = torch.from_numpy(m.astype(bool))
        f = detect(disk, img, max_keypoints=max_features, mask=mask)
        feats.append((f, torch.tensor([img.shape[2], img.shape[1]], dtype=torch.float32)))
    return feats


def _learned_into_database(
    views,
    work,
    names,
    have_masks,
    max_features,
    num_threads,
    dilate_px,
    camera_model,
    seed,
    min_confidence,
    pair_filter=None,
):
    """DISK keypoints (inside the dilated masks) and LightGlue matches of every pair, written into
    ``work/database.db``; then pycolmap's two-view geometric verification, as for SIFT."""
    import pycolmap
    import torch

    from go_core.features.weights import load_disk, load_lightglue

    db_path = work / "database.db"
    pycolmap.Database.open(db_path).close()  # import_images needs the file
    reader = pycolmap.ImageReaderOptions()
    if camera_model:
        reader.camera_model = camera_model
    pycolmap.import_images(
        db_path,
        work / "images",
        camera_mode=pycolmap.CameraMode.SINGLE if camera_model else pycolmap.CameraMode.PER_IMAGE,
        image_names=names,
        options=reader,
    )
    disk, glue = load_disk(), load_lightglue()
    with torch.no_grad(), _torch_threads(num_threads):
        feats = disk_features(disk, views, max_features, dilate_px, have_masks)
        db = pycolmap.Database.open(db_path)
        try:
            ids = {img.name: img.image_id for img in db.read_all_images()}
            for name, (f, _) in zip(names, feats, strict=True):
                # sub-pixel peaks for the geometry (LightGlue matched the whole pixels); COLMAP: centres +0.5
                db.write_keypoints(ids[name], (f.xy_subpixel.numpy() + 0.5).astype(np.float32))
            pairs = []
            for i in range(len(views)):
                for j in range(i + 1, len(views)):
                    if pair_filter is not None and not pair_filter(i, j):
                        continue
                    (fi, si), (fj, sj) = feats[i], feats[j]
                    m, confidence = glue(fi.xy, fi.descriptors, si, fj.xy, fj.descriptors, sj)
                    m = m[confidence > min_confidence]
                    if len(m):
                        db.write_matches(ids[names[i]], ids[names[j]], m.numpy().astype(np.uint32))
                        pairs.append(f"{names[i]} {names[j]}")
        finally:
            db.close()
    pairs_path = work / "pairs.txt"
    pairs_path.write_text("\n".join(pairs) + "\n")
    if pairs:
        pycolmap.verify_matches(db_path, pairs_path, options=_verification(seed))


class _torch_threads:
    """Run torch with ``n`` intra-op threads inside the block (the pose check shares the machine)."""

    def __init__(self, n: int) -> None:
        self.n = max(1, int(n))

    def __enter__(self):
        import torch

        self.old = torch.get_num_threads()
        torch.set_num_threads(self.n)

    def __exit__(self, *exc) -> None:
        import torch

        torch.set_num_threads(self.old)


def extract_and_match(
    views,
    work: Path,
    max_features: int = 4096,
    num_threads: int = 2,
    dilate_px: int = 3,
    peak_threshold: float = PEAK_THRESHOLD,
    use_masks: bool = True,
    camera_model: str | None = None,
    matcher: str = DEFAULT_MATCHER,
    pair_filter=None,
    seed: int = 0,
    min_confidence: float = CHECK_MIN_CONFIDENCE,
    match_threads: int | None = None,
) -> tuple[list[np.ndarray], dict[tuple[int, int], np.ndarray]]:
    """Features + exhaustive matching + geometric verification with pycolmap.

    ``matcher``: ``sift`` (COLMAP's SIFT and its matcher) or ``disk`` (DISK + LightGlue, learned; weights
    from ``go-pipeline weights fetch``). Both keep features inside the (dilated) masks and verify every
    matched pair with COLMAP's two-view geometry. Returns per-view keypoint xy [N,2] (COLMAP pixel
    convention = ours: pixel centres at +0.5) and {(i, j): inlier match index pairs [M,2]} for i < j.
    ``pair_filter(i, j)``: the pairs the learned matcher runs on (default all; SIFT always matches all).
    ``seed``: the RANSAC seed of the verification. ``min_confidence``: LightGlue matches at or below it are
    dropped (``disk`` only; CHECK_MIN_CONFIDENCE / ESTIMATE_MIN_CONFIDENCE). ``match_threads``: the threads
    of COLMAP's SIFT matcher (default ``num_threads``); only 1 repeats exactly (CHECK_MATCH_THREADS).
    """
    import pycolmap

    if matcher not in MATCHERS:
        raise PoseCheckError(f"unknown matcher {matcher!r}; choose one of {', '.join(MATCHERS)}")
    names, have_masks = _write_inputs(views, work, dilate_px, use_masks)
    _quiet(pycolmap)
    if matcher == "sift":
        threads = num_threads if match_threads is None else match_threads
        _sift_into_database(
            views, work, names, have_masks, max_features, threads, peak_threshold, camera_model, seed
        )
    else:
        _learned_into_database(
            views,
            work,
            names,
            have_masks,
            min(max_features, 2048),
            num_threads,
            dilate_px,
            camera_model,
            seed,
            min_confidence,
            pair_filter,
        )
    db = pycolmap.Database.open(work / "database.db")
    try:
        id_to_index = {img.image_id: names.index(img.name) for img in db.read_all_images()}
        keypoints = [np.zeros((0, 2))] * len(views)
        for image_id, idx in id_to_index.items():
            keypoints[idx] = np.asarray(db.read_keypoints(image_id))[:, :2].astype(np.float64)
        pair_ids, geometries = db.read_two_view_geometries()
        matches: dict[tuple[int, int], np.ndarray] = {}
        for pair_id, geom in zip(pair_ids, geometries, strict=True):
            inl = np.asarray(geom.inlier_matches)
            if inl.size == 0:
                continue
            id1, id2 = pycolmap.pair_id_to_image_pair(pair_id)
            i, j = id_to_index[id1], id_to_index[id2]
            if i > j:
                i, j, inl = j, i, inl[:, ::-1]
            matches[(i, j)] = inl.astype(np.int64)
    finally:
        db.close()
    return keypoints, matches
