"""Typed step params: one class per step, pipeline.yaml in step with it, every --set / profile value checked
by name, type and range at plan time, and steps that need another step's settings receive them."""

from __future__ import annotations

import ast
import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import pytest
from go_pipeline.steps.params import CoarseParams, LooParams, RepairParams
from go_pipeline.steps.registry import STEPS, upstream_fields

from go_core.config import field_types, to_mapping
from go_core.errors import PipelineError
from go_pipeline.pipeline import load_pipeline, step_params

PARAMS_CLASSES = {module: declared.params for module, declared in STEPS.items()}

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def pipeline():
    return load_pipeline()


def test_every_packaged_step_is_typed_and_takes_every_default_from_its_class(pipeline):
    """pipeline.yaml writes no default (tests/test_defaults_once.py); the class gives them all."""
    for name, spec in pipeline.steps.items():
        cls = PARAMS_CLASSES.get(spec.module)
        assert cls is not None and spec.params_class is cls, name
        own = [f.name for f in fields(cls) if f.name not in upstream_fields(cls)]
        defaults = to_mapping(cls())
        assert spec.params == {key: defaults[key] for key in own}, name


def test_each_step_annotates_run_with_its_own_class():
    for module, cls in PARAMS_CLASSES.items():
        path = REPO / "steps" / f"{module.rsplit('.', 1)[1]}.py"
        tree = ast.parse(path.read_text())
        run = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "run")
        assert ast.unparse(run.args.args[2].annotation) == cls.__name__, path


def test_steps_have_no_fallback_defaults_or_rename_tables():
    for path in sorted((REPO / "steps").glob("*.py")):
        text = path.read_text()
        assert "params.get(" not in text and "params[" not in text, path
    for path in [*REPO.glob("go_core/**/*.py"), *REPO.glob("steps/*.py")]:
        text = path.read_text()
        assert "PARAM_MAP" not in text and "settings_from" not in text and "config_from_params" not in text, (
            path
        )


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"coarse.iterations": -5}, "--set coarse.iterations=-5: must be >= 0, got -5"),
        ({"coarse.iterations": "many"}, "--set coarse.iterations='many': expected int, got str 'many'"),
        ({"coarse.iterations": 2.5}, "--set coarse.iterations=2.5: expected int, got float 2.5"),
        ({"coarse.random_background": 1}, "--set coarse.random_background=1: expected bool, got int 1"),
        ({"coarse.lambda_dssim": 1.5}, "--set coarse.lambda_dssim=1.5: must be <= 1, got 1.5"),
        ({"coarse.lambda_mask": float("nan")}, "--set coarse.lambda_mask=nan: must be a finite number"),
        ({"coarse.floater_schedule": "cosine"}, "--set coarse.floater_schedule='cosine': must be one of 'code' | 'paper', got 'cosine'"),  # noqa: E501
        ({"hull.init": "cube"}, "--set hull.init='cube': must be one of 'hull' | 'random', got 'cube'"),
        ({"tune.sd15_resolution": 100}, "--set tune.sd15_resolution=100: must be a multiple of 64, got 100"),
        ({"turntable.background": [1, 1]}, "--set turntable.background=[1, 1]: expected 3 values, got 2"),
        ({"turntable.background": [1, 1, 2]}, "--set turntable.background=[1, 1, 2]: must be <= 1, got 2.0"),
        ({"eval.lpips_nets": ["vgg", "squeeze"]}, "--set eval.lpips_nets=['vgg', 'squeeze']: must be one of 'vgg' | 'alex', got 'squeeze'"),  # noqa: E501
        ({"coarse.nope": 1}, "--set coarse.nope=1: step 'coarse' has no param 'nope' (params: "),
        ({"loo.coarse": {}}, "--set loo.coarse={}: loo.coarse is step 'coarse''s params, given to 'loo': set coarse.NAME instead"),  # noqa: E501
        ({"repair.sd15_t_range": [0.9, 0.2]}, "step 'repair': sd15_t_range must be increasing, got [0.9, 0.2]"),  # noqa: E501
        ({"repair.opacity_reset_every": 500}, "step 'repair': opacity_reset_every=500 resets opacities to coarse.opacity_reset_value 0.01, below min_opacity 0.02"),  # noqa: E501
    ],
)  # fmt: skip
def test_bad_set_values_are_one_clear_error(pipeline, overrides, message):
    with pytest.raises(PipelineError) as info:
        pipeline.resolve_params(overrides=overrides)
    text = str(info.value)
    assert text.startswith(message), text  # a command-line value: no file named
    assert "\n" not in text


def test_good_set_values_are_converted(pipeline):
    p = pipeline.resolve_params(
        overrides={"coarse.lambda_mask": 1, "tune.betas": [0.5, 0.9], "coarse.position_lr_init": "1e-3"}
    )
    assert p["coarse"]["lambda_mask"] == 1.0 and isinstance(p["coarse"]["lambda_mask"], float)
    assert p["coarse"]["position_lr_init"] == 0.001
    assert step_params("go_pipeline.steps.tune", p["tune"]).betas == (0.5, 0.9)


def test_profiles_are_checked_against_the_class(tmp_path):
    text = (REPO / "pipeline.yaml").read_text() + "\n  broken:\n    coarse: {iterations: -1}\n"
    path = tmp_path / "pipeline.yaml"
    path.write_text(text)
    with pytest.raises(PipelineError, match=r"profile 'broken': coarse.iterations: must be >= 0, got -1$"):
        load_pipeline(path)


def _with_hull_params(tmp_path, params: str):
    """The packaged pipeline.yaml with ``params: {...}`` (values a user changes) added to the hull step."""
    hull = "    inputs: {scene: scene, mask: mask}\n"
    text = (REPO / "pipeline.yaml").read_text()
    assert text.count(hull) == 1
    path = tmp_path / "pipeline.yaml"
    path.write_text(text.replace(hull, hull + f"    params: {params}\n"))
    return path


def test_pipeline_yaml_values_are_checked_too(tmp_path):
    with pytest.raises(PipelineError, match=r"step 'hull': param num_points: must be >= 1, got 0$"):
        load_pipeline(_with_hull_params(tmp_path, "{num_points: 0}"))
    with pytest.raises(PipelineError, match=r"step 'hull': 'num_pts' is not a setting of HullParams"):
        load_pipeline(_with_hull_params(tmp_path, "{num_pts: 5}"))
    changed = load_pipeline(_with_hull_params(tmp_path, "{num_points: 7}"))
    assert (
        changed.steps["hull"].params["num_points"] == 7
        and changed.resolve_params()["hull"]["num_points"] == 7
    )


def test_loo_and_repair_receive_the_coarse_settings(pipeline):
    p = pipeline.resolve_params(profile="example", overrides={"coarse.lambda_mask": 0.5})
    for step in ("loo", "repair"):
        assert p[step]["coarse"] == p["coarse"]
    loo = step_params("go_pipeline.steps.loo", p["loo"])
    repair = step_params("go_pipeline.steps.repair", p["repair"])
    assert isinstance(loo, LooParams) and isinstance(loo.coarse, CoarseParams)
    assert loo.phase1_config().lambda_mask == 0.5 and loo.phase1_config().iterations == 100
    assert loo.phase2_config().floaters is False and loo.phase2_config().iterations == 60
    assert isinstance(repair, RepairParams)
    config = repair.training_config(sh_degree=2)
    assert config.lambda_mask == 0.5 and config.min_opacity == repair.min_opacity == 0.02
    assert config.position_lr_init == config.position_lr_final == repair.means_lr
    # the repair's own anisotropy weight, not the coarse stage's
    assert repair.coarse.lambda_anisotropy == 0.01
    assert config.lambda_anisotropy == repair.lambda_anisotropy == 0.0
    assert config.densify_from == 50 and config.floaters is False and config.lambda_depth == 0.0


def test_coarse_settings_are_in_the_keys_of_loo_and_repair(tmp_path):
    from go_pipeline.runner import _plan

    scene = tmp_path / "scene"
    scene.mkdir()
    plans = [_plan(scene, None, "example", o, 0, None) for o in ({}, {"coarse.lambda_mask": 0.5})]
    for step in ("loo", "repair"):
        assert plans[0].params[step]["coarse"] != plans[1].params[step]["coarse"]
    assert plans[0].params["hull"] == plans[1].params["hull"]


def test_params_classes_are_torch_free():
    code = (
        "import sys, go_pipeline.pipeline as p; p.load_pipeline().resolve_params(); "
        "print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_field_types_resolve_for_every_class():
    for cls in PARAMS_CLASSES.values():
        assert set(field_types(cls)) >= {f.name for f in fields(cls)}


def test_cli_rejects_an_out_of_range_set_before_anything_runs(tmp_path):
    scene = tmp_path / "scene"
    scene.mkdir()
    (scene / "a.txt").write_text("not read: the plan fails first")
    out = subprocess.run(
        [sys.executable, "-m", "go_pipeline.cli", "run", str(scene), "--set", "coarse.iterations=-5"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert lines[0].endswith("--set coarse.iterations=-5: must be >= 0, got -5"), out.stderr
    assert not (scene / ".go").exists()


def test_status_names_the_upstream_setting_that_changed(tmp_path):
    from go_pipeline.runner import _flat

    assert _flat({"renders": 3, "coarse": {"lambda_mask": 0.5, "iterations": 2}}) == {
        "renders": 3,
        "coarse.lambda_mask": 0.5,
        "coarse.iterations": 2,
    }
