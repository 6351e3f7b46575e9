"""The `scene` step and its artifact (scene.json + views.npz): round trip, determinism, JSON Schema."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from _scene_helpers import write_colmap_scene

from go_core.scene.artifact import (
    Ingest,
    load_scene_artifact,
    load_scene_cameras,
    read_scene_manifest,
    save_scene_artifact,
)
from go_core.scene.loader import load_scene
from go_pipeline.pipeline import step_params

SCHEMA = Path(__file__).resolve().parents[1] / "data_schema" / "scene_manifest.schema.json"


@pytest.fixture(scope="module")
def schema():
    s = json.loads(SCHEMA.read_text())
    jsonschema.Draft202012Validator.check_schema(s)
    return jsonschema.Draft202012Validator(s)


@pytest.fixture(scope="module")
def basket(shared_data):
    return load_scene(shared_data / "sample" / "basket")


def assert_same_scene(a, b, exact: bool = True):
    assert a.format == b.format and a.split_source == b.split_source
    for va, vb in zip(a.train + a.test, b.train + b.test, strict=True):
        assert va.name == vb.name and va.source.name == vb.source.name
        assert (va.camera.width, va.camera.height) == (vb.camera.width, vb.camera.height)
        np.testing.assert_array_equal(va.camera.K, vb.camera.K)  # JSON floats round-trip exactly
        np.testing.assert_array_equal(va.camera.world_to_cam, vb.camera.world_to_cam)
        assert vb.image.dtype == np.float32 and (vb.mask is None) == (va.mask is None)
        if exact:
            np.testing.assert_array_equal(va.image, vb.image)
            if va.mask is not None:
                np.testing.assert_array_equal(va.mask, vb.mask)
        else:  # float16 storage: relative precision 2^-11
            np.testing.assert_allclose(vb.image, va.image, atol=1e-3)
            if va.mask is not None:
                np.testing.assert_allclose(vb.mask, va.mask, atol=1e-3)


def test_round_trip_exact_for_8bit_sources(basket, tmp_path, schema):
    manifest = save_scene_artifact(basket, tmp_path / "a")
    schema.validate(manifest)
    assert json.loads((tmp_path / "a" / "scene.json").read_text()) == manifest
    back = load_scene_artifact(tmp_path / "a")
    assert_same_scene(basket, back, exact=True)
    assert back.root == tmp_path / "a" and back.train[0].source == Path("train/r_0.png")
    with np.load(tmp_path / "a" / "views.npz") as z:
        assert z["train_000_image"].dtype == np.uint8 and z["test_007_mask"].dtype == np.uint8
        assert sorted(z.files)[:2] == ["test_000_image", "test_000_mask"]
    train, test = load_scene_cameras(tmp_path / "a")
    assert [c.name for c in train] == [v.name for v in basket.train] and len(test) == 8


def test_round_trip_float16_after_downscale(shared_data, tmp_path, schema):
    scene = load_scene(shared_data / "real" / "blowtorch", max_size=64)
    manifest = save_scene_artifact(scene, tmp_path / "a", Ingest(max_size=64))
    schema.validate(manifest)
    assert manifest["train"][0]["width"] == 64 and manifest["train"][0]["height"] == 43
    with np.load(tmp_path / "a" / "views.npz") as z:
        assert z["train_000_image"].dtype == np.float16
        assert z["train_000_mask"].shape == (43, 64)
    assert_same_scene(scene, load_scene_artifact(tmp_path / "a"), exact=False)


def test_artifact_bytes_are_deterministic(basket, tmp_path):
    save_scene_artifact(basket, tmp_path / "a")
    save_scene_artifact(basket, tmp_path / "b")
    for name in ("scene.json", "views.npz"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def test_colmap_artifact_records_mask_files(tmp_path, schema):
    root = write_colmap_scene(tmp_path / "c", n=4)
    manifest = save_scene_artifact(load_scene(root), tmp_path / "a")
    schema.validate(manifest)
    cam = manifest["train"][0]
    assert (cam["source"], cam["mask_source"], cam["has_mask"]) == (
        "images/img_0.png",
        "masks/img_0.png",
        True,
    )
    assert manifest["format"] == "colmap" and manifest["split_source"] == "all images"


def test_schema_rejects_malformed_manifests(basket, tmp_path, schema):
    manifest = save_scene_artifact(basket, tmp_path / "a")
    bad = json.loads(json.dumps(manifest))
    bad["train"][0]["K"] = [[1, 0, 0], [0, 1, 0]]
    bad_format = dict(manifest, format="blender")
    one_view = dict(manifest, train=manifest["train"][:1])
    for instance in (bad, bad_format, one_view):
        with pytest.raises(jsonschema.ValidationError):
            schema.validate(instance)


def test_missing_artifact_is_a_clear_error(tmp_path):
    from go_core.errors import SceneError

    with pytest.raises(SceneError, match="scene artifact manifest is missing"):
        read_scene_manifest(tmp_path)


class FakeContext:
    def __init__(self, out_dir: Path) -> None:
        self.step = "scene"
        self.out_dir = out_dir
        self.checkpoint_dir = out_dir / "ckpt"
        self.seed = 0
        self.device = "cpu"
        self.log = logging.getLogger("test.scene")
        self.records: dict = {}

    def record(self, **values) -> None:
        self.records.update(values)


def test_scene_step_writes_the_artifact(shared_data, tmp_path, schema):
    from go_pipeline.steps import scene as step

    ctx = FakeContext(tmp_path / "out")
    step.run(
        ctx,
        {"folder": shared_data / "dev" / "milk"},
        step_params(step.__name__, {"views": 2, "max_size": 128}),
    )
    # dev/milk carries its ground-truth mesh: the scene step copies it for eval's geometry metrics
    assert sorted(p.name for p in ctx.out_dir.iterdir()) == ["mesh_world.npz", "scene.json", "views.npz"]
    manifest = json.loads((ctx.out_dir / "scene.json").read_text())
    schema.validate(manifest)
    assert (manifest["views_requested"], manifest["max_size"]) == (2, 128)
    assert ctx.records["train_views"] == ["train_r_0", "train_r_2"] and ctx.records["test_views"] == 20
    assert ctx.records["resolutions"] == ["128x128"] and ctx.records["masks"] == 22
    scene = load_scene_artifact(ctx.out_dir)
    assert scene.train[0].camera.K[0, 2] == 64.0 and scene.test[19].mask.shape == (128, 128)
