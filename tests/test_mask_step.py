"""The mask step's auto path: u2netp when it is in the weights cache, GrabCut (with a warning) when it is
not, one error naming the file when it is corrupt; the object box, named by any photo of the scene."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from go_core import artifacts as art
from go_core.errors import MissingWeightsError, SceneError
from go_core.scene.artifact import save_scene_artifact
from go_core.scene.mask_edges import is_binary, smooth_binary_edges
from go_core.scene.salient_weights import u2netp_path
from go_core.scene.types import Scene, View
from go_pipeline.pipeline import step_params
from tests._scene_helpers import ball_masks, ring_cameras
from tests._tiny_repair import FakeCtx

pytestmark = pytest.mark.usefixtures("single_thread")
W, H = 120, 80


def _photo(seed: int) -> np.ndarray:
    """A red disc (the object) right of centre and a smaller blue one at the left, on grey."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:H, :W]
    img = np.full((H, W, 3), 0.55, np.float32) + rng.normal(0, 0.02, (H, W, 3)).astype(np.float32)
    img[(yy - 40) ** 2 + (xx - 70) ** 2 < 24**2] = (0.9, 0.15, 0.1)
    img[(yy - 40) ** 2 + (xx - 18) ** 2 < 12**2] = (0.1, 0.2, 0.85)
    return np.clip(img, 0, 1)


def _scene(tmp_path):
    cams = ring_cameras(6, W, H, f=60.0)
    views = [View(c, _photo(i), None, source=f"images/{c.name}.jpg") for i, c in enumerate(cams)]
    out = tmp_path / "scene"
    save_scene_artifact(Scene(tmp_path / "raw", "nerf", views[:4], views[4:]), out)
    return {"scene": out}


def _run(tmp_path, **params):
    from go_pipeline.steps import mask

    ctx = FakeCtx(tmp_path, "mask")
    mask.run(ctx, _scene(tmp_path), step_params(mask.__name__, params))
    info = json.loads((ctx.out_dir / "mask.json").read_text())
    masks = np.load(ctx.out_dir / "masks.npz")
    return ctx, info, [masks[k] for k in sorted(masks.files)]


def test_auto_without_u2netp_falls_back_to_grabcut_and_says_how_to_fetch(tmp_path, monkeypatch, caplog):
    monkeypatch.setenv("GO_PIPELINE_CACHE", str(tmp_path / "empty-cache"))
    with caplog.at_level(logging.WARNING):
        ctx, info, masks = _run(tmp_path, method="auto")
    assert info["method"] == "grabcut" and ctx.records["method"] == "grabcut"
    assert "u2netp is not in the weights cache" in caplog.text and "go-pipeline weights fetch" in caplog.text
    with pytest.raises(MissingWeightsError, match=r"u2netp\.onnx: .*not in the cache"):
        _run(tmp_path, method="u2netp")


def test_a_corrupt_u2netp_is_an_error_not_a_fallback(tmp_path, monkeypatch):
    monkeypatch.setenv("GO_PIPELINE_CACHE", str(tmp_path / "cache"))
    path = u2netp_path()
    path.parent.mkdir(parents=True)
    path.write_bytes(b"\0" * 100)
    with pytest.raises(MissingWeightsError, match=rf"{path}: the auto-mask model u2netp is corrupt"):
        _run(tmp_path, method="auto")


def test_auto_uses_u2netp_and_the_box_picks_the_object(tmp_path):
    if not u2netp_path().is_file():
        pytest.skip("u2netp is not in the weights cache (`go-pipeline weights fetch`)")
    yy, xx = np.mgrid[:H, :W]
    red = (yy - 40) ** 2 + (xx - 70) ** 2 < 24**2
    blue = (yy - 40) ** 2 + (xx - 18) ** 2 < 12**2
    _, info, masks = _run(tmp_path / "plain", method="auto")
    assert info["method"] == "u2netp" and len(masks) == 4
    for m in masks:
        assert (m[red] > 0.5).mean() > 0.9 and (m[blue] > 0.5).mean() < 0.1
    _, info, masks = _run(tmp_path / "box", method="auto", object_box="4,26,33,55@v5.jpg")  # a test view
    assert info["object_box"] == "4,26,33,55@v5.jpg"
    for m in masks:
        assert (m[blue] > 0.5).mean() > 0.9 and (m[red] > 0.5).mean() < 0.1
    with pytest.raises(SceneError, match="names photo 'nope.jpg', which is not a view"):
        _run(tmp_path / "bad", method="u2netp", object_box="4,26,33,55@nope.jpg")


def test_with_enough_posed_views_the_masks_are_voted_through_the_poses(tmp_path):
    """Ten posed photos of a red ball; in one, a red slab joins it (u2netp takes it in, as it takes in a
    turntable disc): the vote over all ten views carves the slab away."""
    if not u2netp_path().is_file():
        pytest.skip("u2netp is not in the weights cache (`go-pipeline weights fetch`)")
    from go_pipeline.steps import mask

    cams = ring_cameras(10, 160, 120, f=150.0, elevation=0.4)
    truth = ball_masks(cams, np.array([0.0, 0.0, 0.1]), 0.45)
    rows = np.nonzero(truth[1].any(1))[0]
    slab = np.zeros_like(truth[1])
    slab[rows.max() - 4 : rows.max() + 20, 20:140] = True
    views = []
    for i, (cam, t) in enumerate(zip(cams, truth, strict=True)):
        img = np.full((120, 160, 3), 0.6, np.float32)
        img[t | (slab if i == 1 else False)] = (0.85, 0.15, 0.1)
        views.append(View(cam, img, None, source=f"{cam.name}.jpg"))
    out = tmp_path / "scene"
    save_scene_artifact(Scene(tmp_path / "raw", "nerf", views[:4], views[4:]), out)
    ctx = FakeCtx(tmp_path, "mask")
    mask.run(ctx, {"scene": out}, step_params(mask.__name__, {"method": "u2netp"}))
    info = json.loads((ctx.out_dir / "mask.json").read_text())
    masks = np.load(ctx.out_dir / "masks.npz")
    voted = masks["train_001"] > 0.5
    assert info["vote_views"] == 10
    assert (voted & truth[1]).sum() / (voted | truth[1]).sum() > 0.85
    assert voted[slab & ~truth[1]].mean() < 0.1


def _provided_scene(tmp_path, soft_first: bool):
    """Four views with provided binary disc masks; the first soft when ``soft_first``."""
    cams = ring_cameras(4, W, H, f=60.0)
    yy, xx = np.mgrid[:H, :W]
    disc = (((yy - 40.3) ** 2 + (xx - 70.6) ** 2) < 23.7**2).astype(np.float32)
    masks = [disc.copy() for _ in cams]
    if soft_first:
        masks[0] = disc * 0.9
    pairs = enumerate(zip(cams, masks, strict=True))
    views = [View(c, _photo(i), m, source=f"images/{c.name}.png") for i, (c, m) in pairs]
    out = tmp_path / "scene"
    save_scene_artifact(Scene(tmp_path / "raw", "nerf", views, []), out)
    stored = [v.mask for v in art.read_scene(out).train]  # as the scene artifact holds them
    assert not is_binary(stored[0]) and all(is_binary(m) for m in stored[1:])
    return {"scene": out}, stored


@pytest.mark.parametrize("edges", ["smooth", "keep"])
def test_provided_binary_masks_get_their_edges_smoothed_or_kept(tmp_path, edges):
    from go_pipeline.steps import mask

    inputs, given = _provided_scene(tmp_path, soft_first=True)
    ctx = FakeCtx(tmp_path, "mask")
    mask.run(ctx, inputs, step_params(mask.__name__, {"method": "provided", "binary_edges": edges}))
    info = json.loads((ctx.out_dir / "mask.json").read_text())
    saved = np.load(ctx.out_dir / "masks.npz")
    made = [saved[k] for k in sorted(saved.files)]
    np.testing.assert_array_equal(made[0], given[0])  # a soft mask is never changed
    assert "edges" not in info["views"][0]
    for m, g, view in zip(made[1:], given[1:], info["views"][1:], strict=True):
        if edges == "smooth":
            np.testing.assert_array_equal(m, smooth_binary_edges(g))
            assert view["edges"] == "smoothed" and 0 < np.count_nonzero((m > 0) & (m < 1))
        else:
            np.testing.assert_array_equal(m, g)
            assert "edges" not in view
