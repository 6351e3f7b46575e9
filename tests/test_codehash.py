"""Code in the cache key: a step's key covers its module, the go_core / step modules it imports
(transitively) and the native kernel sources; changing one invalidates exactly the steps that run it."""

from __future__ import annotations

import ast
import shutil
import textwrap
from pathlib import Path

import pytest
from _runner_toy import make_toy_project

from go_pipeline import codehash
from go_pipeline.runner import pipeline_status, run_pipeline

REPO = Path(__file__).resolve().parents[1]


def test_coarse_code_covers_its_library_and_kernels_scene_does_not():
    coarse = codehash.fingerprint("go_pipeline.steps.coarse").files
    scene = codehash.fingerprint("go_pipeline.steps.scene").files
    for name in (
        "go_pipeline/steps/coarse.py",
        "go_core/coarse/loop.py",  # imported by the step
        "go_core/coarse/losses.py",  # imported by training, transitively
        "go_core/render/__init__.py",  # a package run on the way to go_core.render.cpu
        "go_core/render/csrc/rasterize.cpp",  # native sources of the extension it loads
        "go_core/render/csrc/simd.h",
        "go_core/kernels/csrc/adam.cpp",  # kernels that are not rendering, in the same extension
    ):
        assert name in coarse, name
    assert "go_pipeline/steps/scene.py" in scene and "go_core/scene/artifact.py" in scene
    assert not any(n.startswith("go_core/render/") or n == "go_core/coarse/losses.py" for n in scene)
    assert not any(n.startswith("go_pipeline/") and "/steps/" not in n for n in coarse)  # not the runner


def test_native_sources_list_every_file_the_extension_is_built_from():
    from go_core.render import build

    declared = {(build.HERE / p).resolve() for p in build.NATIVE_SOURCES}
    on_disk = {p.resolve() for d in (REPO / "go_core").rglob("csrc") for p in d.iterdir()}
    assert declared == {p for p in on_disk if p.suffix in (".cpp", ".h", ".cu")}
    assert set(build.SOURCES) | set(build.HEADERS) == set(build.NATIVE_SOURCES)


@pytest.fixture()
def go_core_copy(tmp_path, monkeypatch):
    """A copy of go_core that the code hash reads instead of the real one (edits stay in tmp_path)."""
    root = tmp_path / "go_core"
    shutil.copytree(REPO / "go_core", root, ignore=shutil.ignore_patterns("__pycache__"))
    real = codehash._root_location

    def location(name: str) -> Path:
        return root if name == "go_core" else real(name)

    monkeypatch.setattr(codehash, "_root_location", location)
    return root


STEPS = ["scene", "mask", "hull", "coarse", "eval", "export"]


def _digests() -> dict[str, str]:
    return {s: codehash.fingerprint(f"go_pipeline.steps.{s}").digest for s in STEPS}


def test_editing_a_library_module_changes_exactly_the_steps_that_import_it(go_core_copy):
    before = _digests()
    losses = go_core_copy / "coarse" / "losses.py"
    losses.write_text(losses.read_text() + "\n# a comment is a change too\n")
    after = _digests()
    changed = {s for s in STEPS if before[s] != after[s]}
    assert {"coarse", "eval"} <= changed  # coarse.loop -> losses; eval's metrics -> losses
    assert not changed & {"scene", "mask"}
    files = codehash.fingerprint("go_pipeline.steps.coarse").files
    assert codehash.changed_files({**files, "go_core/coarse/losses.py": "0" * 64}, files) == [
        "go_core/coarse/losses.py"
    ]


ALL_STEPS = [
    "scene", "mask", "depth", "hull", "coarse", "weights", "loo", "noise_pairs", "tune", "repair", "export",
    "mesh", "turntable", "eval",
]  # fmt: skip


@pytest.mark.parametrize(
    ("module", "steps"),
    [
        # the mesh algorithms: only the steps that make or measure meshes (the scene step reads a
        # ground-truth mesh through go_core.mesh.files and go_core.mesh.types alone)
        ("mesh/texture.py", {"mesh"}),
        ("mesh/tsdf.py", {"mesh"}),
        ("mesh/surface.py", {"mesh"}),
        # the photo route's SfM and the matcher: only the ingest, not every step that reads its artifact
        ("photos/sfm.py", {"scene"}),
        ("features/lightglue.py", {"scene"}),
        ("scene/loader.py", {"scene"}),
        # the evaluation protocol: eval alone, not the tuning and the repair that use one metric each
        ("metrics/evaluate.py", {"eval"}),
    ],
)
def test_editing_a_stage_module_reruns_only_the_steps_that_import_it(go_core_copy, module, steps):
    before = {s: codehash.fingerprint(f"go_pipeline.steps.{s}").digest for s in ALL_STEPS}
    path = go_core_copy / module
    path.write_text(path.read_text() + "\n# a comment is a change too\n")
    after = {s: codehash.fingerprint(f"go_pipeline.steps.{s}").digest for s in ALL_STEPS}
    assert {s for s in ALL_STEPS if before[s] != after[s]} == steps


def test_editing_a_kernel_source_changes_the_steps_that_load_the_extension(go_core_copy):
    before = _digests()
    kernel = go_core_copy / "kernels" / "csrc" / "adam.cpp"
    kernel.write_text(kernel.read_text() + "\n// changed\n")
    after = _digests()
    assert before["coarse"] != after["coarse"]
    assert before["scene"] == after["scene"] and before["mask"] == after["mask"]


def test_relative_and_function_level_imports_are_followed(tmp_path):
    toy = make_toy_project(tmp_path)
    pkg = toy.src / toy.pkg
    (pkg / "helpers.py").write_text("X = 1\n")
    (pkg / "inner.py").write_text("def f():\n    from . import helpers\n    return helpers.X\n")
    step = toy.step_file("double")
    step.write_text(step.read_text() + "\nfrom .inner import f  # noqa\n")
    files = codehash.fingerprint(f"{toy.pkg}.double").files
    assert f"{toy.pkg}/inner.py" in files and f"{toy.pkg}/helpers.py" in files
    assert f"{toy.pkg}/helpers.py" not in codehash.fingerprint(f"{toy.pkg}.side").files


def test_a_changed_library_module_reruns_its_steps_and_descendants_and_status_names_it(tmp_path):
    toy = make_toy_project(tmp_path)
    pkg = toy.src / toy.pkg
    (pkg / "lib_double.py").write_text("FACTOR_OFFSET = 0.0\n")
    (pkg / "lib_unused.py").write_text("NOTHING = 1\n")
    step = toy.step_file("double")
    step.write_text(
        step.read_text().replace(
            "import json\n", f"import json\nfrom {toy.pkg}.lib_double import FACTOR_OFFSET\n"
        )
    )
    kw = dict(pipeline_path=toy.pipeline, quiet=True)
    first = run_pipeline(toy.scene, **kw)
    keys = {s.name: s.key for s in first.steps}

    (pkg / "lib_unused.py").write_text("NOTHING = 2\n")  # imported by no step: nothing changes
    assert all(r.state == "fresh" for r in pipeline_status(toy.scene, pipeline_path=toy.pipeline))

    (pkg / "lib_double.py").write_text("FACTOR_OFFSET = 0.0  # same value, different code\n")
    rows = {r.step: r for r in pipeline_status(toy.scene, pipeline_path=toy.pipeline)}
    assert rows["double"].state == "stale"
    assert rows["double"].reason == f"code changed: {toy.pkg}/lib_double.py"
    assert {s for s, r in rows.items() if r.state == "fresh"} == {"ingest", "side"}
    second = run_pipeline(toy.scene, **kw)
    assert second.ran == ["double"]  # same output bytes: train and report stay cached
    assert second.step("double").key != keys["double"]
    assert {s.name: s.key for s in second.steps if s.name != "double"} == {
        k: v for k, v in keys.items() if k != "double"
    }


def test_version_is_an_explicit_override(tmp_path):
    toy = make_toy_project(tmp_path)
    run_pipeline(toy.scene, pipeline_path=toy.pipeline, quiet=True)
    source = toy.step_file("side").read_text()
    toy.step_file("side").write_text(source.replace('VERSION = "1"\n', ""))  # no VERSION: allowed
    row = {r.step: r for r in pipeline_status(toy.scene, pipeline_path=toy.pipeline)}["side"]
    assert row.state == "stale" and row.reason.startswith("version changed 1 -> None; code changed")


def test_steps_of_the_real_pipeline_define_no_version_or_skip_rule():
    """Their code is in the key; a VERSION would be a manual override that nothing needs today, and a
    packaged step's version and skip rules are declared once, in steps/registry.py."""
    for path in sorted((REPO / "steps").glob("*.py")):
        tree = ast.parse(path.read_text())
        names = {
            t.id for n in tree.body if isinstance(n, ast.Assign) for t in n.targets if isinstance(t, ast.Name)
        }
        assert not names & {"VERSION", "SKIP_IF_SKIPPED", "SKIP_IF_EMPTY"}, path


def test_a_syntax_error_in_step_code_is_a_clear_error(tmp_path):
    from go_core.errors import PipelineError

    toy = make_toy_project(tmp_path)
    (toy.src / toy.pkg / "broken.py").write_text(textwrap.dedent("def f(:\n    pass\n"))
    step = toy.step_file("side")
    step.write_text(step.read_text() + f"\nimport {toy.pkg}.broken  # noqa\n")
    with pytest.raises(PipelineError, match=r"broken\.py: cannot parse it to hash the step's code"):
        codehash.fingerprint(f"{toy.pkg}.side")
