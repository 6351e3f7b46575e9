"""Image IO through OpenImageIO (go_core.io.images): formats, scaling, straight alpha, errors."""

from __future__ import annotations

import numpy as np
import pytest

from go_core.io.images import ImageReadError, image_size, read_image, read_mask, split_rgb_alpha, write_png


def _ramp(h: int, w: int, c: int, maxval: int, dtype) -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.integers(0, maxval + 1, size=(h, w, c)).astype(dtype)


def test_png_8bit_round_trip_and_straight_alpha(tmp_path):
    """RGBA PNG alpha is straight: OpenImageIO would premultiply it unless told not to."""
    rgba = _ramp(5, 7, 4, 255, np.uint8)
    rgba[0, 0] = [200, 100, 50, 10]  # low alpha: premultiplying would darken the colour to ~8, 4, 2
    write_png(tmp_path / "a.png", rgba)
    back = read_image(tmp_path / "a.png")
    assert back.dtype == np.float32 and back.shape == (5, 7, 4)
    np.testing.assert_array_equal(back, rgba.astype(np.float32) / np.float32(255))
    np.testing.assert_allclose(back[0, 0] * 255, [200, 100, 50, 10], atol=1e-4)
    assert image_size(tmp_path / "a.png") == (7, 5, 4)


def test_png_16bit_and_jpeg(tmp_path):
    import cv2

    x = _ramp(6, 9, 3, 65535, np.uint16)
    cv2.imwrite(str(tmp_path / "x16.png"), x[..., ::-1])
    np.testing.assert_allclose(read_image(tmp_path / "x16.png"), x / 65535.0, atol=1e-7)
    smooth = np.tile(np.linspace(0, 255, 16, dtype=np.uint8)[None, :, None], (16, 1, 3))
    cv2.imwrite(str(tmp_path / "s.jpg"), smooth, [cv2.IMWRITE_JPEG_QUALITY, 100])
    j = read_image(tmp_path / "s.jpg")
    assert j.shape == (16, 16, 3)
    np.testing.assert_allclose(j, smooth / 255.0, atol=3 / 255)


def test_exr_linear_values_kept_and_unpremultiplied(tmp_path):
    import OpenImageIO as oiio

    rgb = np.array([[[0.25, 2.0, 7.5]]], np.float32)  # linear HDR values above 1 stay as they are
    data = np.concatenate([rgb * 0.5, np.full((1, 1, 1), 0.5, np.float32)], axis=2)  # premultiplied, a = 0.5
    out = oiio.ImageOutput.create(str(tmp_path / "e.exr"))
    assert out.open(str(tmp_path / "e.exr"), oiio.ImageSpec(1, 1, 4, "float"))
    out.write_image(data)
    out.close()
    back = read_image(tmp_path / "e.exr")
    np.testing.assert_allclose(back[0, 0], [0.25, 2.0, 7.5, 0.5], rtol=1e-6)


def test_unreadable_and_missing_files_name_the_file(tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"\x89PNG not really")
    for path, msg in ((bad, "unreadable image"), (tmp_path / "none.png", "image file not found")):
        with pytest.raises(ImageReadError, match=msg) as info:
            read_image(path)
        assert info.value.path == path and "\n" not in str(info.value)


def test_masks_and_channel_split(tmp_path):
    m = np.zeros((4, 6), np.float32)
    m[1:3, 2:5] = 1
    write_png(tmp_path / "m.png", m)
    np.testing.assert_array_equal(read_mask(tmp_path / "m.png"), m)
    write_png(tmp_path / "m3.png", np.repeat(m[..., None], 3, 2))
    np.testing.assert_array_equal(read_mask(tmp_path / "m3.png"), m)
    cut = np.zeros((4, 6, 4), np.float32)
    cut[..., 3] = m  # a cut-out saved as the mask: constant colour, the alpha is the mask
    write_png(tmp_path / "m4.png", cut)
    np.testing.assert_array_equal(read_mask(tmp_path / "m4.png"), m)
    grey = np.full((2, 2, 1), 0.5, np.float32)
    rgb, a = split_rgb_alpha(grey)
    assert rgb.shape == (2, 2, 3) and a is None
