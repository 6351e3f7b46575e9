"""The artifact catalog: file names in one place (go_core.artifacts), the runner's declared outputs from it
(go_pipeline.catalog), and no step spelling a file name."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from go_pipeline.steps.params import PARAMS_CLASSES

from go_core import artifacts as art
from go_pipeline.catalog import STEP_OUTPUTS
from go_pipeline.pipeline import load_pipeline

REPO = Path(__file__).resolve().parents[1]
FILE_NAME = re.compile(r"^[\w.-]+\.(npz|npy|json|png|gif|ply|safetensors|pt|jpg|csv|mp4)$")


def _catalogue() -> list[art.Artifact]:
    return [v for v in vars(art).values() if isinstance(v, art.Artifact)]


def test_each_file_name_is_defined_once():
    files = [a.file for a in _catalogue()]
    assert len(files) == len(set(files)) and all(FILE_NAME.match(f) for f in files)


def test_no_step_spells_a_file_name():
    found = []
    for path in sorted((REPO / "steps").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and FILE_NAME.match(node.value):
                found.append(f"{path.name}:{node.lineno} {node.value!r}")
    assert found == []


def test_the_finder_of_file_names_finds_them():
    assert FILE_NAME.match("gaussians.npz") and FILE_NAME.match("repair_preview.png")
    assert not FILE_NAME.match("a photo of xxy5syt00") and not FILE_NAME.match("scene")


def test_declared_outputs_come_from_the_catalog():
    pipeline = load_pipeline()
    assert set(STEP_OUTPUTS) == set(PARAMS_CLASSES)
    for name, spec in pipeline.steps.items():
        assert spec.outputs == tuple(a.file for a in STEP_OUTPUTS[spec.module]), name
    assert "outputs:" not in (REPO / "pipeline.yaml").read_text()


def test_go_core_formats_use_the_catalog_names():
    from go_core import masking
    from go_core.scene import artifact as scene_artifact

    assert masking.MASKS_FILE == art.MASKS.file
    assert (scene_artifact.MANIFEST, scene_artifact.ARRAYS) == (art.SCENE_INFO.file, art.SCENE_VIEWS.file)


def test_final_model_prefers_a_repaired_set(tmp_path):
    coarse, repair = tmp_path / "coarse", tmp_path / "repair"
    coarse.mkdir()
    repair.mkdir()
    assert art.final_model(coarse, None) == (coarse, "coarse", None)
    assert art.final_model(coarse, repair) == (coarse, "coarse", None)  # no repair.json
    art.write_json(repair, art.REPAIR_INFO, {"status": "skipped", "reason": "no weights"})
    assert art.final_model(coarse, repair)[:2] == (coarse, "coarse")
    art.write_json(repair, art.REPAIR_INFO, {"status": "ok"})
    assert art.final_model(coarse, repair) == (repair, "repair", {"status": "ok"})


def test_scene_and_masks_round_trip_through_the_catalog(tmp_path):
    import numpy as np
    from _scene_helpers import write_nerf_scene

    from go_core.scene.loader import load_scene

    scene = load_scene(write_nerf_scene(tmp_path / "raw", n_train=3, n_test=1))
    from go_core.scene.artifact import Ingest

    manifest = art.write_scene(tmp_path / "scene", scene, Ingest(views_requested=3))
    assert sorted(p.name for p in (tmp_path / "scene").iterdir()) == sorted(
        [art.SCENE_INFO.file, art.SCENE_VIEWS.file]
    )
    back = art.read_scene(tmp_path / "scene")
    assert [v.name for v in back.train] == [c["name"] for c in manifest["train"]]
    for a, b in zip(scene.train + scene.test, back.train + back.test, strict=True):
        assert np.array_equal(a.image, b.image) and np.allclose(a.camera.K, b.camera.K)
    train, test = art.read_scene_cameras(tmp_path / "scene")
    assert [c.name for c in train + test] == [v.name for v in back.train + back.test]
    masks = [v.mask for v in back.train]
    art.write_masks(tmp_path / "mask", masks)
    got = art.read_masks(tmp_path / "mask", len(masks))
    assert all(np.array_equal(a, b) for a, b in zip(masks, got, strict=True))


def test_steps_read_artifacts_through_the_catalog():
    """No step calls a format module's loader or writer directly (go_core.artifacts is the one door)."""
    names = ("load_scene_artifact", "save_scene_artifact", "load_scene_cameras", "load_masks", "save_masks")
    direct = re.compile(r"\b(" + "|".join(names) + r")\b")
    found = [
        f"{p.name}:{i}"
        for p in sorted((REPO / "steps").glob("*.py"))
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if direct.search(line)
    ]
    assert found == []
