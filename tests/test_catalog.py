"""The artifact catalog: file names in one place (go_core.artifacts), the runner's declared outputs from it
(go_pipeline.steps.registry), and no step spelling a file name."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from go_pipeline.steps.registry import STEPS

from go_core import artifacts as art
from go_pipeline.pipeline import load_pipeline

REPO = Path(__file__).resolve().parents[1]
FILE_NAME = re.compile(r"^[\w.-]+\.(npz|npy|json|png|gif|ply|safetensors|pt|jpg|csv|mp4|glb)$")


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


def test_declared_outputs_come_from_the_registry():
    pipeline = load_pipeline()
    assert {spec.module for spec in pipeline.steps.values()} == set(STEPS)
    for name, spec in pipeline.steps.items():
        assert spec.outputs == tuple(a.file for a in STEPS[spec.module].outputs), name
    assert "outputs:" not in (REPO / "pipeline.yaml").read_text()


def test_optional_outputs_are_declared_and_shown():
    """Files a step writes only in some runs (the repaired ``gaussians.npz``: only when repair ran) are
    catalogue names, disjoint from the required ones, and ``dag`` shows them."""
    from go_pipeline.commands.dag import dag_lines

    pipeline = load_pipeline()
    assert "gaussians.npz" in pipeline.steps["repair"].optional_outputs
    names = {a.file for a in _catalogue()}
    for name, spec in pipeline.steps.items():
        assert not set(spec.outputs) & set(spec.optional_outputs), name
        assert set(spec.optional_outputs) <= names, name
    (repair_line,) = [line for line in dag_lines(pipeline) if ". repair " in line]
    assert "gaussians.npz" in repair_line
