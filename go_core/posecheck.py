"""COLMAP-checked poses: do the given cameras agree with the images?

1. pycolmap extracts SIFT features (inside each view's mask when it has one, so a turntable background
   cannot vote) and matches them exhaustively with two-view geometric verification. Verification uses
   only the images, never the given poses.
2. Verified matches are chained into tracks (union-find over (image, keypoint)); tracks that hit one
   image twice are dropped.
3. Every observation is checked against the GIVEN poses, which stay fixed: the track's point is
   triangulated (linear DLT, given K and world_to_cam) from the track's OTHER images, and reprojected
   into the held-out image. Leaving the image out means a wrong pose cannot pull the point towards its own
   observation, and a wrong pose in another image only affects the few tracks it shares.
4. Per image: median (robust) and mean reprojection error over its observations; an image whose median
   error is above ``threshold_px`` (scaled to the image size) is flagged.

``reconstruct`` runs pycolmap incremental SfM for scenes without poses (go_core.pose_estimate verifies its
result before anything uses it).
"""

from __future__ import annotations

import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from go_core.camera import Camera
from go_core.epipolar import epipolar_distances
from go_core.errors import EmptyHullError, GoError
from go_core.io.images import to_uint8
from go_core.match_silhouettes import PairTurns, pair_turns, refutation_floor
from go_core.pose_verify import MIN_COVERAGE, optical_axis_angles

WIDE_BASELINE_DEG = 60.0  # disagreeing pairs wider than this are no evidence (mostly repeated texture)
SELF_MATCH_SHARE = 0.5  # more disagreeing pairs than this share, with no single view to blame: no evidence
PEAK_THRESHOLD = 0.002  # SIFT DoG peak threshold: below COLMAP's 0.0067 for the smooth objects we scan


class PoseCheckError(GoError):
    """The pose check could not run (too few views, no matches, ...)."""


@dataclass
class ImagePoseResult:
    name: str
    verified_pairs: int  # image pairs with enough geometrically verified matches
    consistent_pairs: int  # ... of which agree with the given poses (epipolar error <= threshold)
    best_pair_epipolar_px: float | None
    observations: int  # leave-one-out reprojections checked (tracks with >= 3 views)
    median_px: float | None  # median leave-one-out reprojection error
    p90_px: float | None
    flagged: bool
    status: str = "ok"  # ok | flagged | unverified
    reason: str = ""
    mask_coverage: float | None = None  # fraction of its mask covered by the other views' hull


@dataclass
class PoseCheckReport:
    threshold_px: float
    images: list[ImagePoseResult]
    num_tracks: int
    num_verified_pairs: int
    flagged: list[str] = field(default_factory=list)
    unverified: list[str] = field(default_factory=list)
    wide_pairs_ignored: int = 0  # disagreeing pairs too far apart to count as evidence
    refuted_pairs_ignored: int = 0  # disagreeing pairs whose matches ask for turns the silhouettes refute
    masks_consistent: bool | None = None  # None: no masks, or too many views to check them
    mask_problem: str = ""
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.flagged and self.masks_consistent is not False

    def to_dict(self) -> dict:
        d = asdict(self)
        d["ok"] = self.ok
        return d


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
    """pycolmap SIFT extraction (inside the masks) and exhaustive matching into ``work/database.db``."""
    import pycolmap

    db_path = work / "database.db"
    reader = pycolmap.ImageReaderOptions()
    if have_masks:
        reader.mask_path = str(work / "masks")
    if camera_model:
        reader.camera_model = camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = num_threads
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
) -> tuple[list[np.ndarray], dict[tuple[int, int], np.ndarray]]:
    """Features + exhaustive matching + geometric verification with pycolmap.

    ``matcher``: ``sift`` (COLMAP's SIFT and its matcher) or ``disk`` (DISK + LightGlue, learned; weights
    from ``go-pipeline weights fetch``). Both keep features inside the (dilated) masks and verify every
    matched pair with COLMAP's two-view geometry. Returns per-view keypoint xy [N,2] (COLMAP pixel
    convention = ours: pixel centres at +0.5) and {(i, j): inlier match index pairs [M,2]} for i < j.
    ``pair_filter(i, j)``: the pairs the learned matcher runs on (default all; SIFT always matches all).
    ``seed``: the RANSAC seed of the verification. ``min_confidence``: LightGlue matches at or below it are
    dropped (``disk`` only; CHECK_MIN_CONFIDENCE / ESTIMATE_MIN_CONFIDENCE).
    """
    import pycolmap

    if matcher not in MATCHERS:
        raise PoseCheckError(f"unknown matcher {matcher!r}; choose one of {', '.join(MATCHERS)}")
    names, have_masks = _write_inputs(views, work, dilate_px, use_masks)
    _quiet(pycolmap)
    if matcher == "sift":
        _sift_into_database(
            views, work, names, have_masks, max_features, num_threads, peak_threshold, camera_model, seed
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


def build_tracks(num_keypoints: list[int], matches: dict[tuple[int, int], np.ndarray]) -> list[np.ndarray]:
    """Union-find tracks: each an array [[view, keypoint], ...] with every view at most once, >= 2 views."""
    offsets = np.concatenate([[0], np.cumsum(num_keypoints)])
    parent = np.arange(int(offsets[-1]))

    def find(x: int) -> int:
        root = x
        while parent[root] != root:
            root = parent[root]
        while parent[x] != root:
            parent[x], x = root, parent[x]
        return root

    for (i, j), m in matches.items():
        for a, b in m:
            ra, rb = find(offsets[i] + a), find(offsets[j] + b)
            if ra != rb:
                parent[rb] = ra
    groups: dict[int, list[int]] = {}
    used = set()
    for (i, j), m in matches.items():
        used.update((offsets[i] + m[:, 0]).tolist())
        used.update((offsets[j] + m[:, 1]).tolist())
    for node in used:
        groups.setdefault(find(node), []).append(node)
    tracks = []
    for nodes in groups.values():
        view_of = np.searchsorted(offsets, nodes, side="right") - 1
        if len(set(view_of.tolist())) != len(nodes) or len(nodes) < 2:
            continue  # inconsistent track (one image twice) or trivial
        kp = np.asarray(nodes) - offsets[view_of]
        tracks.append(np.stack([view_of, kp], axis=1))
    return tracks


def triangulate_dlt(projections: np.ndarray, points2d: np.ndarray) -> np.ndarray:
    """Linear (DLT) triangulation of one point from P [K,3,4] and pixel coords [K,2]."""
    rows = []
    for P, (u, v) in zip(projections, points2d, strict=True):
        rows.append(u * P[2] - P[0])
        rows.append(v * P[2] - P[1])
    A = np.asarray(rows)
    A /= np.linalg.norm(A, axis=1, keepdims=True) + 1e-12
    _, _, vt = np.linalg.svd(A)
    X = vt[-1]
    return X[:3] / X[3] if abs(X[3]) > 1e-12 else np.full(3, np.nan)


def leave_one_out_errors(
    cameras: list[Camera], keypoints: list[np.ndarray], tracks: list[np.ndarray], min_views: int = 3
) -> list[list[float]]:
    """Per view, the reprojection errors (px) of its observations against points triangulated from the
    other views of each track (tracks with >= ``min_views`` views)."""
    P = np.stack([c.K @ c.world_to_cam[:3] for c in cameras])
    errors: list[list[float]] = [[] for _ in cameras]
    for track in tracks:
        if len(track) < min_views:
            continue
        vids, kps = track[:, 0], track[:, 1]
        xy = np.stack([keypoints[v][k] for v, k in zip(vids, kps, strict=True)])
        for t in range(len(track)):
            others = np.arange(len(track)) != t
            X = triangulate_dlt(P[vids[others]], xy[others])
            if not np.all(np.isfinite(X)):
                continue
            cam = cameras[vids[t]]
            uv, z = cam.project(X[None])
            zo = np.array([cameras[v].project(X[None])[1][0] for v in vids[others]])
            if z[0] <= 0 or np.any(zo <= 0):
                errors[vids[t]].append(float("inf"))  # behind a camera: certainly inconsistent
                continue
            errors[vids[t]].append(float(np.linalg.norm(uv[0] - xy[t])))
    return errors


def _blame_inconsistent_pairs(
    n: int, pair_err: dict, consistent: dict, min_consistent_pairs: int
) -> dict[int, bool]:
    """Images to flag for pairs that disagree with the given poses: {image: ambiguous}.

    A disagreeing pair is ignored when both images agree with enough other views (repeated texture).
    Otherwise it needs a culprit among its unsupported images: greedily the image(s) with the most
    unexplained disagreeing pairs are flagged, until every such pair touches a flagged image. Two images
    that only ever matched each other and disagree cannot be told apart: both are flagged (ambiguous)."""
    from collections import Counter

    support = Counter(i for p in consistent for i in p)
    unsupported = {i for i in range(n) if support[i] < min_consistent_pairs}
    bad = [p for p in pair_err if p not in consistent and (p[0] in unsupported or p[1] in unsupported)]
    blamed: dict[int, bool] = {}
    while True:
        open_pairs = [p for p in bad if p[0] not in blamed and p[1] not in blamed]
        if not open_pairs:
            return blamed
        counts = Counter(i for p in open_pairs for i in p if i in unsupported)
        top = max(counts.values())
        culprits = [i for i, c in counts.items() if c == top]
        for i in culprits:
            blamed[i] = any(j in culprits for p in open_pairs if i in p for j in p if j != i)


def _mask_coverages(views, max_views: int) -> tuple[list[float] | None, str]:
    """Silhouette consistency (``go_core.pose_verify.mask_coverage``): evidence that needs no texture.
    Per view the coverage (None when not checked) and the note or problem ("" when there is none)."""
    from go_core.pose_verify import mask_coverage

    if any(v.mask is None for v in views):
        return None, "masks not checked: some views have no mask"
    if len(views) > max_views:
        return None, f"masks not checked: more than {max_views} views"
    try:
        cov = mask_coverage(
            [v.camera for v in views], [v.mask for v in views], max_pixels=600, samples_per_ray=128
        )
    except EmptyHullError:
        return [], "the visual hull of the masks is empty under the given poses"
    return [float(c) for c in cov], ""


def _mask_evidence(views, report: PoseCheckReport, coverage: list[float] | None, note: str) -> None:
    """Record the silhouette consistency (``_mask_coverages``) in ``report``."""
    if coverage is None:
        report.notes.append(note)
        return
    if not coverage:
        report.masks_consistent, report.mask_problem = False, note
        return
    for res, c in zip(report.images, coverage, strict=True):
        res.mask_coverage = c
    low = sorted((c, v.name) for v, c in zip(views, coverage, strict=True) if c < MIN_COVERAGE)
    report.masks_consistent = not low
    if low:
        report.mask_problem = (
            "the masks disagree with the poses: the other views' hull covers only "
            + ", ".join(f"{c:.2f} of {n}" for c, n in low)
            + f" (< {MIN_COVERAGE:g}; one wrong camera lowers several views)"
        )


def check_poses(
    views,
    threshold_px: float = 1.5,
    reference_size: int = 256,
    min_consistent_pairs: int = 1,
    min_matches: int = 15,
    max_features: int = 4096,
    num_threads: int = 2,
    workdir: Path | None = None,
    wide_baseline_deg: float = WIDE_BASELINE_DEG,
    mask_check_max_views: int = 32,
    matcher: str = DEFAULT_MATCHER,
    max_pair_angle_deg: float = 90.0,
) -> PoseCheckReport:
    """Check the poses of ``views`` (``go_core.scene.types.View``: image, optional mask, camera).

    A verified image pair (>= ``min_matches`` inliers) is *consistent* with the given poses when the median
    epipolar distance of its matches is at most the threshold. Repeated textures (a carton's identical
    sides) can verify wrong pairs, so an image only needs ``min_consistent_pairs`` consistent partners; an
    image with verified pairs of which fewer agree is flagged; one without any verified pair is
    ``unverified`` (textureless objects, very wide baselines): the check cannot speak for it.
    A pair whose optical axes (given poses) are more than ``wide_baseline_deg`` apart and that disagrees is
    no evidence against either view: across such baselines almost every verified pair of the dev scenes
    with correct poses that disagrees is repeated texture (docs/evaluation.md); one that agrees still counts.
    With masks, a disagreeing pair counts only if turning one of its views about its centre to fit the
    matches leaves the masks agreeing at least as well as the given poses (``go_core.match_silhouettes``):
    the matches of a symmetric object matched to itself ask for turns the silhouettes refute, a turned
    camera's ask for its error back.
    Tracks from consistent pairs then give the leave-one-out reprojection error, which also catches
    errors epipolar geometry is blind to (e.g. a shift along the viewing axis). A wrong camera also
    raises the errors of the views it shares tracks with, so images are blamed greedily: the worst one
    above the threshold is flagged and its observations removed, then the errors are recomputed.
    ``threshold_px`` is for a ``reference_size``-pixel image and scales with the longest image side.
    With masks (and at most ``mask_check_max_views`` views), the silhouettes are checked too
    (``masks_consistent``): that needs no texture, so it speaks for textureless and wide-baseline views.
    The learned matcher (one network pass per pair) only matches pairs whose given optical axes are at most
    ``max_pair_angle_deg`` apart: of the SIFT pairs beyond 90° of the dev and real scenes, 1 of 81 agreed.
    When the pairs disagree set-wide while the masks agree (``matches_disagree_set_wide``: a symmetric
    object matched to itself), the features are no evidence: every view is unverified, none flagged.
    """
    if len(views) < 2:
        raise PoseCheckError(f"the pose check needs at least 2 views, got {len(views)}")
    cameras = [v.camera for v in views]
    angles = optical_axis_angles(cameras)
    with tempfile.TemporaryDirectory(prefix="go-posecheck-", dir=workdir) as tmp:
        keypoints, matches = extract_and_match(
            views,
            Path(tmp),
            max_features,
            num_threads,
            matcher=matcher,
            pair_filter=lambda i, j: angles[i, j] <= max_pair_angle_deg,
        )
    floor = LEARNED_MIN_THRESHOLD_PX if matcher == "disk" else 0.0
    thr = [max(threshold_px * max(c.width, c.height) / reference_size, floor) for c in cameras]
    coverage, mask_note = _mask_coverages(views, mask_check_max_views)
    masks_agree = bool(coverage) and min(coverage) >= MIN_COVERAGE
    pair_err: dict[tuple[int, int], float] = {}
    consistent: dict[tuple[int, int], np.ndarray] = {}
    wide_ignored: dict[tuple[int, int], float] = {}
    disagreeing: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}  # their matched points
    refuted: dict[tuple[int, int], PairTurns] = {}
    blamed_errors: dict[int, list[float]] = {}
    for (i, j), m in matches.items():
        if len(m) < min_matches:
            continue
        points = (keypoints[i][m[:, 0]], keypoints[j][m[:, 1]])
        d = epipolar_distances(cameras[i], cameras[j], *points)
        err = float(np.median(d))
        limit = max(thr[i], thr[j])
        if err <= limit:
            pair_err[(i, j)] = err
            consistent[(i, j)] = m[d <= limit]  # single stray matches of a consistent pair are dropped
        elif angles[i, j] > wide_baseline_deg:
            wide_ignored[(i, j)] = float(angles[i, j])
        else:
            pair_err[(i, j)] = err
            disagreeing[(i, j)] = points
    # the silhouettes judge the disagreeing pairs that could blame a view (one without enough agreeing
    # partners: _blame_inconsistent_pairs ignores the others), unless the masks agree and the pairs disagree
    # set-wide: then every view ends unverified anyway (_overrule_self_matches). Each turn costs seconds.
    agrees = {p: p in consistent for p in pair_err}
    support = np.bincount(np.asarray(list(consistent), np.int64).reshape(-1), minlength=len(views))
    if coverage and not (masks_agree and matches_disagree_set_wide(len(views), agrees)):
        masks, coverage_floor = [v.mask for v in views], refutation_floor(min(coverage), MIN_COVERAGE)
        for (i, j), points in disagreeing.items():
            if min(support[i], support[j]) >= min_consistent_pairs:
                continue
            turns = pair_turns(cameras, masks, (i, j), points, max(thr[i], thr[j]), coverage_floor)
            if turns.refuted(coverage_floor):
                refuted[(i, j)] = turns
                del pair_err[(i, j)]
    tracks = build_tracks([len(k) for k in keypoints], consistent)
    blamed: list[int] = []
    while True:
        kept = [t[~np.isin(t[:, 0], blamed)] for t in tracks]
        errors = leave_one_out_errors(cameras, keypoints, kept)
        medians = [
            np.median(e) if len(e) >= 10 and i not in blamed else -np.inf for i, e in enumerate(errors)
        ]
        worst = int(np.argmax(medians))
        if not medians[worst] > thr[worst]:
            break
        blamed.append(worst)
        blamed_errors[worst] = errors[worst]

    epi_blamed = _blame_inconsistent_pairs(len(views), pair_err, consistent, min_consistent_pairs)
    results, flagged, unverified = [], [], []
    for idx, (view, errs) in enumerate(zip(views, errors, strict=True)):
        mine = {p: e for p, e in pair_err.items() if idx in p}
        wide = [a for p, a in wide_ignored.items() if idx in p]
        n_ok = sum(p in consistent for p in mine)
        e = np.asarray(blamed_errors.get(idx, errs), np.float64)
        med = float(np.median(e)) if e.size else None
        res = ImagePoseResult(
            name=view.name,
            verified_pairs=len(mine),
            consistent_pairs=n_ok,
            best_pair_epipolar_px=min(mine.values()) if mine else None,
            observations=int(e.size),
            median_px=med,
            p90_px=float(np.percentile(e, 90)) if e.size else None,
            flagged=False,
        )
        if idx in epi_blamed:
            res.flagged, res.status = True, "flagged"
            partners = [views[j].name for p in mine if p not in consistent for j in p if j != idx]
            res.reason = (
                f"agrees with {n_ok} of {len(mine)} matched views (best epipolar error "
                f"{res.best_pair_epipolar_px:.1f} px > {thr[idx]:.2f} px)"
            )
            if epi_blamed[idx]:
                res.reason += (
                    f"; its only disagreeing partner {partners[0]} is flagged too: cannot tell which"
                )
        elif idx in blamed and med is not None:
            res.flagged, res.status = True, "flagged"
            res.reason = f"median reprojection error {med:.2f} px > {thr[idx]:.2f} px"
        elif not mine and (turns := {p: t for p, t in refuted.items() if idx in p}):
            res.status = "unverified"
            partners = ", ".join(views[j].name for p in turns for j in p if j != idx)
            asked = ", ".join(f"{t.turn_deg[p.index(idx)]:.0f}°" for p, t in turns.items())
            res.reason = (
                f"its matches with {partners} disagree with the poses, but turning either view to fit them "
                f"(this one: {asked}) breaks the silhouettes' agreement: self-matches, no evidence"
            )
        elif not mine and wide:
            res.status = "unverified"
            res.reason = (
                f"its only matches are with views {min(wide):.0f}-{max(wide):.0f}° away and disagree: "
                f"beyond {wide_baseline_deg:g}° such matches are mostly repeated texture: no evidence"
            )
        elif not mine:
            res.status, res.reason = "unverified", "no image pair with enough verified matches"
        elif n_ok < min_consistent_pairs:
            res.status, res.reason = "unverified", "its verified pairs are all with flagged views"
        if res.flagged:
            flagged.append(view.name)
        elif res.status == "unverified":
            unverified.append(view.name)
        results.append(res)
    report = PoseCheckReport(
        threshold_px,
        results,
        len(tracks),
        len(pair_err) + len(wide_ignored) + len(refuted),
        flagged,
        unverified,
        len(wide_ignored),
        len(refuted),
    )
    if not matches:
        report.notes.append("no verified feature matches between any two views (no texture, or far apart)")
    _mask_evidence(views, report, coverage, mask_note)
    _overrule_self_matches(report, agrees)  # wide pairs: no evidence; refuted pairs still disagree
    return report


def matches_disagree_set_wide(
    num_views: int, agrees: dict[tuple[int, int], bool], share: float = SELF_MATCH_SHARE
) -> bool:
    """Whether the verified pairs (``agrees``: pair → agrees with the poses) disagree too broadly for any
    one camera to explain: more than ``share`` of them disagree, and still do once the view in the most
    disagreeing pairs is set aside. Disagreeing pairs wider than ``WIDE_BASELINE_DEG`` are left out, as in
    the check: dev/milk's identical carton sides match across wide baselines with correct poses.

    A wrong camera disagrees only in its own pairs; removing it leaves the others agreeing. An object that
    looks the same from several sides (a plate, a bowl: rotationally symmetric and textureless) is matched
    to itself across views by a confident matcher: the pairs verify (a consistent two-view geometry) and
    disagree with correct poses everywhere. Measured with DISK + LightGlue on dev/plate and
    dev/white_bowl, all 24 views with their correct poses: most pairs disagree on plate (this rule then
    holds), 9 of 19 on white_bowl (it does not: the silhouettes refute those 9, ``match_silhouettes``)."""
    disagree = [p for p, ok in agrees.items() if not ok]
    if len(disagree) <= share * len(agrees):
        return False
    counts = np.bincount(np.asarray(disagree).ravel(), minlength=num_views)
    worst = int(np.argmax(counts))
    rest = [ok for p, ok in agrees.items() if worst not in p]
    rest_disagree = rest.count(False)
    return rest_disagree >= 3 and rest_disagree > share * len(rest)


def _overrule_self_matches(report: PoseCheckReport, agrees: dict[tuple[int, int], bool]) -> None:
    """Features say nothing when they disagree set-wide while the masks agree with the poses
    (``matches_disagree_set_wide``): every view is unverified instead of flagged, with the reason. With the
    masks disagreeing, or without masks, the flags stand (the poses may be what is wrong)."""
    if report.masks_consistent is not True:
        return
    if not matches_disagree_set_wide(len(report.images), agrees):
        return
    reason = (
        f"features inconclusive: {list(agrees.values()).count(False)} of {len(agrees)} verified pairs "
        "disagree with the poses, more than one wrong camera explains, while the masks agree: a symmetric "
        "or repetitive object matches itself across views"
    )
    for res in report.images:
        res.flagged, res.status, res.reason = False, "unverified", reason
    report.flagged = []
    report.unverified = [r.name for r in report.images]
    report.notes.append(reason)


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
