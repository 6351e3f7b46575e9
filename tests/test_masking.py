"""Masks: validation of provided masks, GrabCut from the border, an ONNX salient-object model."""

from __future__ import annotations

import numpy as np
import pytest

from go_core.errors import MissingWeightsError, SceneError
from go_core.scene.masking import OnnxSegmenter, grabcut_mask, load_masks, save_masks, validate_mask

pytestmark = pytest.mark.usefixtures("single_thread")  # small tensors: one thread is faster


def _disc_image(size=64, seed=0):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:size, :size]
    disc = ((yy - size * 0.5) ** 2 + (xx - size * 0.45) ** 2) < (size * 0.25) ** 2
    img = np.empty((size, size, 3), np.float32)
    img[:] = (0.15, 0.35, 0.8)  # blue background
    img[disc] = (0.9, 0.3, 0.1)  # red object
    img += rng.normal(0, 0.02, img.shape).astype(np.float32)
    return np.clip(img, 0, 1), disc


def _iou(a, b):
    return (a & b).sum() / (a | b).sum()


def test_validate_mask_errors_name_the_view():
    ok = np.zeros((8, 8), np.float32)
    ok[2:5, 2:5] = 1
    validate_mask(ok, (8, 8), "train/r_0.png")
    with pytest.raises(SceneError, match="r_1.png.*empty"):
        validate_mask(np.zeros((8, 8), np.float32), (8, 8), "train/r_1.png")
    with pytest.raises(SceneError, match=r"\[0, 1\]"):
        validate_mask(ok * 2, (8, 8), "x")
    with pytest.raises(SceneError, match="image is"):
        validate_mask(ok, (8, 9), "x")
    bad = ok.copy()
    bad[0, 0] = np.nan
    with pytest.raises(SceneError, match="non-finite"):
        validate_mask(bad, (8, 8), "x")


def test_grabcut_segments_a_centred_object():
    img, disc = _disc_image()
    m = grabcut_mask(img, iterations=5)
    assert m.dtype == np.float32 and set(np.unique(m)) <= {0.0, 1.0}
    assert _iou(m > 0.5, disc) > 0.9


def test_onnx_segmenter_with_a_tiny_model(tmp_path):
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper, numpy_helper

    # saliency = red - blue per pixel (a 1x1 convolution), on a fixed 48x48 input
    w = numpy_helper.from_array(np.array([1.0, 0.0, -1.0], np.float32).reshape(1, 3, 1, 1), "w")
    node = helper.make_node("Conv", ["x", "w"], ["y"])
    graph = helper.make_graph(
        [node],
        "sal",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3, 48, 48])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 1, 48, 48])],
        [w],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    path = tmp_path / "sal.onnx"
    onnx.save(model, str(path))
    seg = OnnxSegmenter(path, normalisation="isnet")
    assert seg.size == 48
    img, disc = _disc_image(64)
    m = seg(img)
    assert m.shape == (64, 64) and 0.0 <= m.min() and m.max() <= 1.0
    assert _iou(m > 0.5, disc) > 0.9
    with pytest.raises(MissingWeightsError, match="not found"):
        OnnxSegmenter(tmp_path / "missing.onnx")


def test_masks_artifact_round_trip(tmp_path):
    masks = [np.random.default_rng(i).random((5, 7)).astype(np.float32) for i in range(3)]
    save_masks(tmp_path, masks)
    back = load_masks(tmp_path, 3)
    assert all(np.array_equal(a, b) for a, b in zip(masks, back, strict=False))
    with pytest.raises(SceneError, match="3 masks for 4"):
        load_masks(tmp_path, 4)
