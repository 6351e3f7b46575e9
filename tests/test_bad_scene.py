"""Malformed scenes: each problem gives one clear SceneError line naming the file and what is wrong, and
``validate_scene`` lists every problem of a scene at once."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from _scene_helpers import disk_rgba, edit_json, write_colmap_scene, write_nerf_scene

from go_core.errors import GoError, SceneError
from go_core.io.images import write_png
from go_core.scene.loader import load_scene
from go_core.scene.validate import validate_scene


@pytest.fixture
def nerf(tmp_path):
    return write_nerf_scene(tmp_path / "nerf")


@pytest.fixture
def colmap(tmp_path):
    return write_colmap_scene(tmp_path / "colmap", n=6, text=True)


def raises(root, match: str, path=None, **kw) -> SceneError:
    with pytest.raises(SceneError, match=match) as info:
        load_scene(root, **kw)
    err = info.value
    assert isinstance(err, GoError) and "\n" not in str(err)
    if path is not None:
        assert err.path == path, (err.path, path)
        assert str(err).startswith(f"{path}: ")
    return err


def test_missing_image(nerf):
    (nerf / "train" / "r_2.png").unlink()
    raises(nerf, r"image not found \(referenced by transforms_train.json frame 2", nerf / "train" / "r_2.png")


def test_unreadable_image(nerf):
    (nerf / "test" / "r_1.png").write_bytes(b"this is not a png")
    raises(nerf, r"unreadable image \(", nerf / "test" / "r_1.png")


def test_truncated_image(nerf):
    p = nerf / "train" / "r_0.png"
    p.write_bytes(p.read_bytes()[:60])
    raises(nerf, r"unreadable image", p)


def test_image_mask_size_mismatch(tmp_path):
    root = write_nerf_scene(tmp_path / "m", rgba=False)
    mask = root / "masks" / "train" / "r_1.png"
    write_png(mask, np.ones((10, 12), np.float32))
    raises(root, r"mask is 12x10 but image r_1.png is 32x24", mask)


def test_image_size_differs_from_json(nerf):
    write_png(nerf / "train" / "r_3.png", disk_rgba(20, 20, 0))
    raises(nerf, r"image r_3.png is 20x20 but its camera says 32x24", nerf / "transforms_train.json")


def test_empty_mask(nerf):
    img = disk_rgba(32, 24, 0)
    img[..., 3] = 0
    write_png(nerf / "train" / "r_1.png", img)
    raises(nerf, r"alpha mask is empty \(no pixel > 0.5\)", nerf / "train" / "r_1.png")


def test_all_ones_mask_file(tmp_path):
    root = write_nerf_scene(tmp_path / "m", rgba=False)
    mask = root / "masks" / "test" / "r_0.png"
    write_png(mask, np.ones((24, 32), np.float32))
    raises(root, r"mask is all ones \(covers the whole image\)", mask)


def test_fully_opaque_alpha_everywhere_means_no_masks(nerf):
    """RGBA files whose alpha is opaque in every view carry no mask: accepted, masks dropped."""
    for p in list((nerf / "train").glob("*.png")) + list((nerf / "test").glob("*.png")):
        img = disk_rgba(32, 24, 0)
        img[..., 3] = 1
        write_png(p, img)
    scene = load_scene(nerf)
    assert all(v.mask is None for v in scene.train + scene.test)


def test_non_orthonormal_rotation(nerf):
    def scale(d):
        m = np.array(d["frames"][1]["transform_matrix"])
        m[:3, :3] *= 2.0
        d["frames"][1]["transform_matrix"] = m.tolist()

    edit_json(nerf / "transforms_train.json", scale)
    raises(nerf, r"frame 1 \(./train/r_1\): rotation is not orthonormal", nerf / "transforms_train.json")


def test_reflection_rotation(nerf):
    def mirror(d):
        m = np.array(d["frames"][0]["transform_matrix"])
        m[:3, 0] *= -1
        d["frames"][0]["transform_matrix"] = m.tolist()

    edit_json(nerf / "transforms_test.json", mirror)
    raises(nerf, r"rotation has determinant −1", nerf / "transforms_test.json")


def test_nan_in_pose(nerf):
    def nan(d):
        d["frames"][2]["transform_matrix"][0][3] = float("nan")

    edit_json(nerf / "transforms_train.json", nan)
    raises(nerf, r"frame 2 \(./train/r_2\): pose contains NaN/inf", nerf / "transforms_train.json")


def test_inf_in_intrinsics(nerf):
    edit_json(nerf / "transforms_train.json", lambda d: d.update(fl_y=float("inf")))
    raises(nerf, r"intrinsic fl_y is inf \(NaN/inf\)", nerf / "transforms_train.json")


def test_no_focal_length(nerf):
    edit_json(nerf / "transforms_test.json", lambda d: [d.pop(k) for k in ("fl_x", "camera_angle_x")])
    raises(nerf, r"no focal length \(need fl_x or camera_angle_x\)", nerf / "transforms_test.json")


def test_duplicate_image_names(nerf):
    edit_json(nerf / "transforms_train.json", lambda d: d["frames"].append(dict(d["frames"][0])))
    raises(nerf, r"duplicate image 'r_0.png': used by two views", nerf / "transforms_train.json")


def test_fewer_than_two_training_views(nerf):
    edit_json(nerf / "transforms_train.json", lambda d: d.update(frames=d["frames"][:1]))
    raises(nerf, r"fewer than 2 training views \(1 usable\)", nerf / "transforms_train.json")


def test_views_larger_than_available(nerf):
    raises(
        nerf,
        r"views=8 requested but the scene has only 4 training views",
        nerf / "transforms_train.json",
        views=8,
    )


def test_invalid_json(nerf):
    (nerf / "transforms_test.json").write_text('{"frames": [ }')
    raises(nerf, r"invalid JSON \(line 1 column 14", nerf / "transforms_test.json")


def test_missing_transforms_and_sparse(tmp_path):
    (tmp_path / "empty").mkdir()
    raises(
        tmp_path / "empty",
        r"not a scene folder: no transforms_train.json .* and no sparse/0",
        tmp_path / "empty",
    )
    only_test = write_nerf_scene(tmp_path / "t")
    (only_test / "transforms_train.json").unlink()
    raises(only_test, r"missing transforms_train.json", only_test / "transforms_train.json")
    (tmp_path / "c" / "sparse").mkdir(parents=True)
    raises(
        tmp_path / "c",
        r"missing COLMAP model: expected sparse/0/cameras.bin",
        tmp_path / "c" / "sparse" / "0",
    )
    raises(tmp_path / "nope", r"scene folder not found", tmp_path / "nope")


def test_split_indices_out_of_range(colmap):
    (colmap / "sparse_4.txt").write_text("0 1 2 99\n")
    raises(
        colmap,
        r"split indices \[99\] out of range: 6 registered images \(0-5\)",
        colmap / "sparse_4.txt",
        views=4,
    )


def test_colmap_views_larger_than_available_and_bad_split_file(colmap):
    (colmap / "sparse_test.txt").write_text("0 1")
    raises(
        colmap,
        r"views=5 requested but only 4 training images are available",
        colmap / "sparse" / "0",
        views=5,
    )
    (colmap / "sparse_test.txt").write_text("0, 1")
    raises(colmap, r"split file must hold whitespace-separated integer indices", colmap / "sparse_test.txt")


def test_split_train_test_overlap(colmap):
    (colmap / "sparse_2.txt").write_text("0 3")
    (colmap / "sparse_test.txt").write_text("3 5")
    raises(
        colmap,
        r"indices \[3\] are in both the training split \(sparse_2.txt\)",
        colmap / "sparse_test.txt",
        views=2,
    )


def test_unknown_camera_model_text(colmap):
    cams = colmap / "sparse" / "0" / "cameras.txt"
    lines = cams.read_text().splitlines()
    lines = [ln.replace("PINHOLE", "FOOBAR") if ln.startswith("2 ") else ln for ln in lines]
    cams.write_text("\n".join(lines) + "\n")
    raises(colmap, r"line \d+: unknown camera model 'FOOBAR' \(camera 2\)", cams)


def test_unsupported_camera_model_binary(tmp_path):
    from _scene_helpers import ring_cameras, write_colmap_model

    root = write_colmap_scene(tmp_path / "fe", n=3, text=False)
    shutil.rmtree(root / "sparse")
    write_colmap_model(
        root / "sparse" / "0",
        ring_cameras(3),
        [f"img_{i}.png" for i in range(3)],
        text=False,
        model="OPENCV_FISHEYE",
        extra_params=[0.1, 0, 0, 0],
    )
    raises(
        root,
        r"camera 1 \(OPENCV_FISHEYE\): unsupported camera model OPENCV_FISHEYE \(supported: PINHOLE",
        root / "sparse" / "0",
    )


def test_colmap_nan_pose(colmap):
    imgs = colmap / "sparse" / "0" / "images.txt"
    lines = imgs.read_text().splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.endswith("img_2.png"))
    tok = lines[i].split()
    tok[5] = "nan"  # TX
    lines[i] = " ".join(tok)
    imgs.write_text("\n".join(lines) + "\n")
    raises(colmap, r"line \d+: image img_2.png has NaN/inf in its pose", imgs)


def test_colmap_missing_image_and_duplicate_names(colmap):
    (colmap / "images" / "img_4.png").unlink()
    raises(
        colmap,
        r"image not found \(registered in the COLMAP model as 'img_4.png'\)",
        colmap / "images" / "img_4.png",
    )
    imgs = colmap / "sparse" / "0" / "images.txt"
    imgs.write_text(imgs.read_text().replace("img_4.png", "img_3.png"))
    raises(colmap, r"duplicate image name 'img_3.png' \(image ids 4 and 5\)", colmap / "sparse" / "0")


def test_bad_views_param(nerf):
    raises(nerf, r"views=1: choose 0 \(the scene's own split\) or at least 2", nerf, views=1)


def test_validate_collects_every_problem(nerf):
    """One validate run lists all problems (not just the first) and prints them."""
    (nerf / "train" / "r_0.png").unlink()
    (nerf / "test" / "r_1.png").write_bytes(b"garbage")
    edit_json(
        nerf / "transforms_train.json", lambda d: d["frames"][2]["transform_matrix"][1].__setitem__(2, 5.0)
    )
    img = disk_rgba(32, 24, 0)
    img[..., 3] = 0
    write_png(nerf / "test" / "r_0.png", img)
    report = validate_scene(nerf)
    assert not report.ok
    expected = [
        (nerf / "train" / "r_0.png", "image not found"),
        (nerf / "transforms_train.json", "frame 2 (./train/r_2): rotation is not orthonormal"),
        (nerf / "test" / "r_1.png", "unreadable image"),
        (nerf / "test" / "r_0.png", "alpha mask is empty"),
    ]
    assert len(report.problems) == len(expected), report.problems
    for path, msg in expected:
        assert any(p.startswith(f"{path}: {msg}") for p in report.problems), (path, msg, report.problems)
    text = report.summary()
    assert text.splitlines()[0] == f"{nerf}: 4 problems found"
    assert all(f"  - {p}" in text for p in report.problems)
    # the good views were still read
    assert [v.name for v in report.scene.train] == ["train_r_1", "train_r_3"]


def test_validate_collects_colmap_text_problems(colmap):
    cams = colmap / "sparse" / "0" / "cameras.txt"
    cams.write_text(
        cams.read_text().replace("1 PINHOLE", "1 WEIRD").replace("3 PINHOLE 32 24 30", "3 PINHOLE 32 24 nan")
    )
    report = validate_scene(colmap)
    assert not report.ok and report.scene is not None and report.scene.train == []
    assert any("unknown camera model 'WEIRD' (camera 1)" in p for p in report.problems)
    assert any("camera 3 (PINHOLE) has NaN/inf parameters" in p for p in report.problems)
    assert json.dumps(report.problems)  # plain strings
