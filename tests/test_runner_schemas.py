"""The JSON Schemas in data_schema/ are valid, accept what the code writes and reject what it must not."""

from __future__ import annotations

import copy
import json

import pytest

from go_pipeline.manifest import schema_problems
from go_pipeline.resources import schema_path


@pytest.mark.parametrize("name", ["step_manifest", "scene_manifest"])
def test_schema_is_valid_json_schema(name):
    import jsonschema

    schema = json.loads(schema_path(name).read_text())
    jsonschema.validators.validator_for(schema).check_schema(schema)
    assert schema["$id"] == f"go-pipeline/{name.replace('_', '-')}"


def test_scene_manifest_schema_accepts_the_scene_artifact():
    from go_core.scene.artifact import scene_manifest
    from go_core.scene.validate import validate_scene
    from go_pipeline.resources import example_scene_path

    report = validate_scene(example_scene_path())
    assert report.ok, report.summary()
    manifest = scene_manifest(report.scene)
    assert schema_problems("scene_manifest", manifest) == []
    bad = copy.deepcopy(manifest)
    bad["train"][0]["K"] = [[1, 0, 0], [0, 1, 0]]
    bad["format"] = "blender"
    del bad["test"][0]["has_mask"]
    problems = schema_problems("scene_manifest", bad)
    assert len(problems) == 3
    assert problems[0] == "at format: 'blender' is not one of ['nerf', 'colmap', 'photos']"
    assert any(p.startswith("at test/0: 'has_mask' is a required property") for p in problems)
    assert any(p.startswith("at train/0/K: ") for p in problems)


def test_step_manifest_schema_rejects_bad_values():
    good = {
        "schema": "go-pipeline/step-manifest",
        "schema_version": 1,
        "step": "coarse",
        "key": "a" * 64,
        "version": "1",
        "code": {"go_pipeline/steps/coarse.py": "9" * 64},
        "function": "go_pipeline.steps.coarse:run",
        "seed": 0,
        "params": {"iterations": 5},
        "inputs": {
            "scene": {"step": "scene", "key": "b" * 64, "content_hash": "c" * 64},
            "folder": {"step": None, "key": None, "content_hash": "d" * 64, "path": "/x"},
        },
        "outputs": {"gaussians.npz": "e" * 64},
        "content_hash": "f" * 64,
        "wall_s": 1.0,
        "cpu_s": 2.0,
        "peak_mem_mb": 100.0,
        "device": "cpu",
        "libraries": {"python": "3.11.7"},
        "started": "2026-11-21T07:00:00.000Z",
        "finished": "2026-11-21T07:00:01.000Z",
        "record": {},
    }
    assert schema_problems("step_manifest", good) == []
    bad = copy.deepcopy(good)
    bad["key"] = "XYZ"
    bad["wall_s"] = -1
    bad["started"] = "yesterday"
    bad["code"] = {"go_core/coarse/losses.py": "not a hash"}
    assert [p.split(":")[0] for p in schema_problems("step_manifest", bad)] == [
        "at code/go_core/coarse/losses.py",
        "at key",
        "at started",
        "at wall_s",
    ]
