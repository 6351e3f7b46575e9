"""Scene readers on the shared dev/real scenes and on COLMAP models written with pycolmap."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from _scene_helpers import ring_cameras, write_colmap_model, write_colmap_scene, write_nerf_scene

from go_core.camera import Camera
from go_core.io.images import read_image, write_png
from go_core.scene.common import farthest_point_choice
from go_core.scene.loader import load_scene
from go_core.scene.validate import validate_scene


@pytest.fixture(scope="module")
def milk(shared_data):
    return load_scene(shared_data / "dev" / "milk")


def test_nerf_dev_scene_cameras_and_images(milk, shared_data):
    assert milk.format == "nerf"
    assert (len(milk.train), len(milk.test)) == (4, 20)
    cam = milk.train[0].camera
    f = 0.5 * 256 / np.tan(0.5 * 0.6981316804885864)  # from camera_angle_x
    np.testing.assert_allclose(cam.K, [[f, 0, 128], [0, f, 128], [0, 0, 1]], rtol=1e-9)
    # README: cameras at distance 3.2 looking at the origin; train views at elevation 20°
    for v in milk.train + milk.test:
        assert np.linalg.norm(v.camera.center) == pytest.approx(3.2, abs=1e-4)
        to_origin = -v.camera.center / np.linalg.norm(v.camera.center)
        assert v.camera.forward @ to_origin > 0.9999
        uv, z = v.camera.project(np.zeros((1, 3)))
        np.testing.assert_allclose(uv[0], [128, 128], atol=1e-3)
    elev = np.degrees(np.arcsin(milk.train[0].camera.center[2] / 3.2))
    assert elev == pytest.approx(20.0, abs=1e-3)
    # pixels: straight RGB in [0, 1] and the fractional alpha as the mask
    v = milk.train[0]
    raw = read_image(shared_data / "dev" / "milk" / "train" / "r_0.png")
    assert v.image.shape == (256, 256, 3) and v.mask.shape == (256, 256)
    np.testing.assert_array_equal(v.image, raw[..., :3])
    np.testing.assert_array_equal(v.mask, raw[..., 3])
    assert 0 < np.mean((v.mask > 0) & (v.mask < 1)) < 0.05  # anti-aliased rim


@pytest.mark.parametrize("name", ["milk", "alphabet_soup", "basket", "plate", "white_bowl"])
def test_mesh_vertices_project_inside_alpha(milk, shared_data, name):
    """End-to-end convention check: the ground-truth mesh projects onto the alpha of every view."""
    scene = milk if name == "milk" else load_scene(shared_data / "dev" / name)
    verts = np.load(shared_data / "dev" / name / "mesh_world.npz")["vertices"].astype(np.float64)
    for v in scene.train + scene.test:
        uv, z = v.camera.project(verts)
        assert (z > 0).all()
        col, row = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        inside = (col >= 0) & (col < v.camera.width) & (row >= 0) & (row < v.camera.height)
        assert inside.all()
        a = v.mask[row, col]
        assert np.mean(a > 0) > 0.99, v.name
        assert np.mean(a > 0.5) > 0.85, v.name
    # a principal-point error would be visible: shifting by 1.5 pixels loses coverage
    v = scene.train[0]
    shifted = Camera(
        v.name,
        v.camera.width,
        v.camera.height,
        v.camera.K + np.array([[0, 0, 1.5], [0, 0, 0], [0, 0, 0]]),
        v.camera.world_to_cam,
    )
    uv, _ = shifted.project(verts)
    a = v.mask[np.floor(uv[:, 1]).astype(int), np.floor(uv[:, 0]).astype(int)]
    uv0, _ = v.camera.project(verts)
    a0 = v.mask[np.floor(uv0[:, 1]).astype(int), np.floor(uv0[:, 0]).astype(int)]
    assert np.mean(a > 0.5) < np.mean(a0 > 0.5)


def _silhouette(cam: Camera, verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Mesh silhouette sampled at pixel centres (i + 0.5, j + 0.5): a tiny exact triangle rasterizer."""
    uv, _ = cam.project(verts)
    tri = uv[faces]  # [F, 3, 2]
    lo = np.floor(tri.min(1) - 0.5).astype(int) + 1  # first pixel whose centre can be inside
    hi = np.floor(tri.max(1) - 0.5).astype(int)
    keep = np.nonzero((hi >= lo).all(1))[0]  # most triangles cover no pixel centre at all
    out = np.zeros((cam.height, cam.width), bool)
    for f in keep:
        (x0, y0), (x1, y1) = lo[f], hi[f]
        X, Y = np.meshgrid(np.arange(x0, x1 + 1) + 0.5, np.arange(y0, y1 + 1) + 0.5)
        a, b, c = tri[f]
        e = [(q[0] - p[0]) * (Y - p[1]) - (q[1] - p[1]) * (X - p[0]) for p, q in ((a, b), (b, c), (c, a))]
        inside = ((e[0] >= 0) & (e[1] >= 0) & (e[2] >= 0)) | ((e[0] <= 0) & (e[1] <= 0) & (e[2] <= 0))
        out[y0 : y1 + 1, x0 : x1 + 1] |= inside
    return out


def test_mesh_silhouette_matches_alpha_to_a_fraction_of_a_pixel(milk, shared_data):
    """The pixel-centre convention (+0.5) is right: the silhouette IoU is ~0.9998 (README: verifier 0.9994+),
    and moving the principal point by half a pixel drops it below 0.99."""
    mesh = np.load(shared_data / "dev" / "milk" / "mesh_world.npz")
    verts, faces = mesh["vertices"].astype(np.float64), mesh["faces"]
    v = milk.train[1]
    alpha = v.mask > 0.5

    def iou(cam):
        sil = _silhouette(cam, verts, faces)
        return (sil & alpha).sum() / (sil | alpha).sum()

    assert iou(v.camera) > 0.999
    K = v.camera.K.copy()
    K[:2, 2] += 0.5
    assert iou(Camera(v.name, v.camera.width, v.camera.height, K, v.camera.world_to_cam)) < 0.99


@pytest.mark.parametrize("name,size", [("blowtorch", (400, 267)), ("ethiopian_head", (400, 400))])
def test_real_scenes(shared_data, name, size):
    scene = load_scene(shared_data / "real" / name)
    assert (len(scene.train), len(scene.test)) == (4, 8)
    lo, hi = {"blowtorch": (2.88, 7.30), "ethiopian_head": (4.54, 4.81)}[name]
    for v in scene.train + scene.test:
        cam = v.camera
        assert (cam.width, cam.height) == size and v.image.shape == (size[1], size[0], 3)
        assert lo - 0.01 <= np.linalg.norm(cam.center) <= hi + 0.01
        assert set(np.unique(v.mask)) <= {0.0, 1.0}  # binary alpha
        assert v.image[v.mask == 0].mean() > 0.05  # background not blanked
        # README: the common look-at point (the origin) lies inside every mask
        uv, z = cam.project(np.zeros((1, 3)))
        assert z[0] > 0 and v.mask[int(uv[0, 1]), int(uv[0, 0])] == 1.0
    if name == "blowtorch":
        K = scene.train[0].camera.K
        expected = [665.0589771955881, 665.1059778300189, 200.00000000000003, 133.5]  # the json's values
        np.testing.assert_allclose([K[0, 0], K[1, 1], K[0, 2], K[1, 2]], expected)


def test_camera_angle_y_and_defaults(tmp_path):
    """camera_angle_x/_y without fl_x/fl_y/cx/cy: focal lengths from the angles, principal point w/2, h/2."""
    root = write_nerf_scene(tmp_path / "s", w=32, h=24)
    for split in ("train", "test"):
        p = root / f"transforms_{split}.json"
        d = json.loads(p.read_text())
        for k in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
            d.pop(k)
        d["camera_angle_y"] = 2 * np.arctan(12 / 25.0)
        p.write_text(json.dumps(d))
    s = load_scene(root)
    K = s.train[0].camera.K
    np.testing.assert_allclose([K[0, 0], K[1, 1], K[0, 2], K[1, 2]], [30.0, 25.0, 16.0, 12.0], rtol=1e-12)


def test_views_choice_is_farthest_point_and_deterministic(tmp_path):
    root = write_nerf_scene(tmp_path / "s", n_train=8, n_test=0)  # 8 cameras 45° apart
    s2 = load_scene(root, views=2)
    s4 = load_scene(root, views=4)
    # ring of 8: the farthest from view 0 is the opposite one; 4 views spread at 90°
    assert [v.name for v in s2.train] == ["train_r_0", "train_r_4"]
    assert [v.name for v in s4.train] == ["train_r_0", "train_r_2", "train_r_4", "train_r_6"]
    assert [v.name for v in load_scene(root, views=4).train] == [v.name for v in s4.train]
    assert len(s4.test) == 0 and "farthest-point" in s4.split_source
    assert farthest_point_choice(ring_cameras(5), 5) == [0, 1, 2, 3, 4]


def test_max_size_downscale_scales_K_per_axis(shared_data):
    full = load_scene(shared_data / "real" / "blowtorch")
    small = load_scene(shared_data / "real" / "blowtorch", max_size=100)
    v, vs = full.train[0], small.train[0]
    assert (vs.camera.width, vs.camera.height) == (100, 67)
    assert vs.image.shape == (67, 100, 3) and vs.mask.shape == (67, 100)
    np.testing.assert_allclose(vs.camera.K[0], v.camera.K[0] * 100 / 400)
    np.testing.assert_allclose(vs.camera.K[1], v.camera.K[1] * 67 / 267)
    # area filter: the mean colour is kept
    assert abs(vs.image.mean() - v.image.mean()) < 0.01
    # the look-at point still projects to the same relative image position
    uv, _ = v.camera.project(np.zeros((1, 3)))
    uvs, _ = vs.camera.project(np.zeros((1, 3)))
    np.testing.assert_allclose(uvs[0] / [100, 67], uv[0] / [400, 267], atol=1e-9)


@pytest.mark.parametrize("text", [False, True], ids=["bin", "txt"])
def test_colmap_model_from_dev_scene_matches_nerf_reader(milk, tmp_path, text):
    """Write the dev scene as a COLMAP model (pycolmap), read it back: the same cameras and pixels."""
    import pycolmap

    root = tmp_path / "colmap"
    views = [("train", v) for v in milk.train] + [("test", v) for v in milk.test[:4]]
    names = [f"{split}_{v.name.split('_')[-1]}.png" for split, v in views]
    for name, (_, v) in zip(names, views, strict=True):
        write_png(root / "images" / name, v.image)
        write_png(root / "masks" / name, v.mask)
    write_colmap_model(root / "sparse" / "0", [v.camera for _, v in views], names, text=text)
    order = sorted(range(len(names)), key=lambda i: names[i])
    (root / "sparse_4.txt").write_text("\n".join(str(order.index(i)) for i in range(4)))
    (root / "sparse_test.txt").write_text(" ".join(str(order.index(i)) for i in range(4, 8)))
    assert (root / "sparse" / "0" / ("cameras.txt" if text else "cameras.bin")).is_file()

    scene = load_scene(root, views=4)
    assert scene.format == "colmap"
    assert scene.split_source == "sparse_4.txt + sparse_test.txt"
    got = scene.train + scene.test
    assert [v.source.name for v in got] == sorted(names[:4]) + sorted(names[4:])
    by_name = dict(zip(names, [v for _, v in views], strict=True))
    recon = pycolmap.Reconstruction(str(root / "sparse" / "0"))
    X = np.array([[0.1, -0.2, 0.3]])
    for v in got:
        ref = by_name[v.source.name]
        np.testing.assert_allclose(v.camera.K, ref.camera.K, atol=1e-6)
        np.testing.assert_allclose(v.camera.world_to_cam, ref.camera.world_to_cam, atol=1e-6)
        np.testing.assert_array_equal(v.image, ref.image)
        np.testing.assert_array_equal(v.mask, ref.mask)
        # a known point projects to the same pixel with our camera, the NeRF camera and pycolmap itself
        uv, _ = v.camera.project(X)
        uv_ref, _ = ref.camera.project(X)
        im = recon.find_image_with_name(v.source.name)
        uv_colmap = im.project_point(X[0])
        np.testing.assert_allclose(uv[0], uv_ref[0], atol=1e-6)
        np.testing.assert_allclose(uv[0], uv_colmap, atol=1e-6)


def test_colmap_default_split_and_farthest_choice(tmp_path):
    root = write_colmap_scene(tmp_path / "c", n=6, text=False)
    s = load_scene(root)
    assert (len(s.train), len(s.test), s.split_source) == (6, 0, "all images")
    assert s.train[0].mask_source.name == "img_0.png"
    s3 = load_scene(root, views=3)  # no sparse_3.txt: spread choice, the others become test views
    # ring of 6: 0, then the opposite 3, then the first of the four tied at 60° (ties: lowest index)
    assert [v.name for v in s3.train] == ["img_0", "img_1", "img_3"]
    assert [v.name for v in s3.test] == ["img_2", "img_4", "img_5"]
    (root / "sparse_test.txt").write_text("5\n")
    (root / "sparse_2.txt").write_text("1 3\n")
    s0 = load_scene(root)  # views=0 with exactly one sparse_N.txt uses it
    assert [v.name for v in s0.train] == ["img_1", "img_3"] and [v.name for v in s0.test] == ["img_5"]


def test_colmap_opencv_distortion_is_undistorted(tmp_path):
    """An OPENCV camera: the image is resampled onto the pinhole camera with the same fx, fy, cx, cy."""
    import pycolmap

    w, h = 64, 48
    params = [60.0, 62.0, 32.3, 23.9, -0.12, 0.03, 0.002, -0.001]
    K = np.array([[60.0, 0, 32.3], [0, 62.0, 23.9], [0, 0, 1]])

    def pattern(xn, yn):  # a smooth pattern of the pinhole image, in pinhole pixel units (period 16 px)
        u, v = xn * 60 + 32.3, yn * 62
        return 0.5 + 0.25 * np.sin(2 * np.pi * u / 16) + 0.2 * np.cos(2 * np.pi * v / 20)

    colmap_cam = pycolmap.Camera(model="OPENCV", width=w, height=h, params=params, camera_id=1)
    yy, xx = np.mgrid[0:h, 0:w]
    centres = np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], 1).astype(np.float64)
    xy = colmap_cam.cam_from_img(centres)  # distorted pixel centre → normalised undistorted coordinates
    distorted = pattern(xy[:, 0], xy[:, 1]).reshape(h, w).astype(np.float32)
    cams = ring_cameras(3, w, h)
    root = tmp_path / "d"
    names = [f"im{i}.png" for i in range(3)]
    for n in names:
        write_png(root / "images" / n, np.repeat(distorted[..., None], 3, 2))
    cams = [Camera(c.name, w, h, K, c.world_to_cam) for c in cams]
    write_colmap_model(root / "sparse" / "0", cams, names, text=True, model="OPENCV", extra_params=params[4:])
    scene = load_scene(root)
    v = scene.train[0]
    np.testing.assert_allclose(v.camera.K, K)
    truth = pattern((xx + 0.5 - 32.3) / 60, (yy + 0.5 - 23.9) / 62)
    valid = np.zeros((h, w), bool)
    valid[6:-6, 6:-6] = True  # away from the border where the distorted photo has no data
    err = np.abs(v.image[..., 0] - truth)[valid]
    assert err.max() < 0.02  # bilinear resampling + 8-bit quantisation
    # the check is sensitive: no undistortion, or a half-pixel convention slip, gives much larger errors
    assert np.abs(distorted - truth)[valid].max() > 0.05
    half_px = pattern((xx - 32.3) / 60, (yy - 23.9) / 62)
    assert np.abs(v.image[..., 0] - half_px)[valid].max() > 0.05


def test_validate_reports_facts(shared_data, tmp_path):
    report = validate_scene(shared_data / "real" / "blowtorch")
    assert report.ok and report.problems == []
    text = report.summary()
    assert "OK (nerf scene)" in text and "400x267 (12 views)" in text
    assert "fx=665.06 fy=665.11 cx=200.00 cy=133.50" in text
    assert "transforms_train.json + transforms_test.json" in text and "train views : 4" in text
    root = tmp_path / "copy"
    shutil.copytree(shared_data / "sample" / "basket", root)
    assert validate_scene(root, views=2).facts()["train_views"] == 2


def test_rgb_plus_mask_files(tmp_path):
    root = write_nerf_scene(tmp_path / "m", rgba=False)
    s = load_scene(root)
    v = s.train[1]
    assert v.mask_source == root / "masks" / "train" / "r_1.png"
    assert set(np.unique(v.mask)) == {0.0, 1.0}


def test_colmap_legacy_text_model_without_rigs_and_frames(tmp_path):
    """Models from COLMAP < 3.12 (GaussianObject's data) have only cameras/images/points3D files."""
    root = write_colmap_scene(tmp_path / "legacy", n=4, text=True)
    ref = load_scene(root)
    for name in ("rigs.txt", "frames.txt"):
        (root / "sparse" / "0" / name).unlink()
    got = load_scene(root)
    assert [v.name for v in got.train] == [v.name for v in ref.train] == ["img_0", "img_1", "img_2", "img_3"]
    for a, b in zip(got.train, ref.train, strict=True):
        np.testing.assert_array_equal(a.camera.world_to_cam, b.camera.world_to_cam)
        np.testing.assert_array_equal(a.camera.K, b.camera.K)
