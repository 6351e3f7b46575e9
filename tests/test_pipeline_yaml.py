"""pipeline.yaml loading and param resolution: the DAG order, profiles, --set typing, and every malformed
pipeline / --set / --profile case with its exact one-line message."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from go_core.errors import PipelineError
from go_pipeline.pipeline import load_pipeline, parse_set_argument, step_rules

MOD = "test_pipeline_yaml_mod"


@pytest.fixture()
def step_module(tmp_path, monkeypatch):
    """An importable module with VERSION and run, and one without VERSION."""
    src = tmp_path / "src"
    src.mkdir()
    (src / f"{MOD}.py").write_text('VERSION = "7"\n\ndef run(ctx, inputs, params):\n    pass\n')
    (src / f"{MOD}_nover.py").write_text("def run(ctx, inputs, params):\n    pass\n")
    monkeypatch.syspath_prepend(str(src))
    return src


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "pipeline.yaml"
    p.write_text(textwrap.dedent(text).lstrip())
    return p


GOOD = f"""
version: 1
steps:
  b:
    function: {MOD}:run
    inputs: {{x: a, raw: "@scene"}}
    outputs: [b.txt]
    params: {{n: 3, rate: 0.5, flag: false, name: "x", items: [1, 2], anything: null}}
  a:
    function: {MOD}:run
    inputs: {{raw: "@scene"}}
    outputs: [a.txt]
    params: {{}}
  c:
    function: {MOD}:run
    inputs: {{x: b, y: a}}
    outputs: [c.txt]
profiles:
  fast: {{b: {{n: 1, rate: 2}}}}
  dotted: {{b.name: "y"}}
"""


def test_good_pipeline_order_and_params(tmp_path, step_module):
    p = load_pipeline(write(tmp_path, GOOD))
    assert p.order == ["a", "b", "c"]  # topological, not file order
    assert p.ancestors("c") == {"a", "b"}
    assert p.descendants("a") == {"b", "c"}
    params = p.resolve_params("fast", {"b.flag": True, "b.items": [3]})
    assert params["b"] == {"n": 1, "rate": 2.0, "flag": True, "name": "x", "items": [3], "anything": None}
    assert isinstance(params["b"]["rate"], float)  # an int is accepted for a float param and converted
    assert p.resolve_params("dotted")["b"]["name"] == "y"
    assert p.resolve_params(None, {"b.rate": "1e-3"})["b"]["rate"] == 0.001  # YAML 1.1 reads 1e-3 as str
    assert p.resolve_params(None, {"b": {"anything": {"k": [1]}}})["b"]["anything"] == {"k": [1]}
    assert step_rules(p.steps["a"], p.path).version == "7"


def test_set_values_are_parsed_as_yaml():
    assert parse_set_argument("coarse.iterations=500") == ("coarse.iterations", 500)
    assert parse_set_argument("a.b=0.25") == ("a.b", 0.25)
    assert parse_set_argument("a.b=true") == ("a.b", True)
    assert parse_set_argument("a.b=[1, 2]") == ("a.b", [1, 2])
    assert parse_set_argument("a.b=hello world") == ("a.b", "hello world")
    assert parse_set_argument("a.b=") == ("a.b", "")


def test_packaged_pipeline_loads_and_no_step_needs_a_version_override():
    p = load_pipeline()
    assert p.order[0] == "scene" and {"mask", "hull", "coarse", "eval"} <= set(p.steps)
    for spec in p.steps.values():
        assert step_rules(spec, p.path).version is None  # their code is in the key
    for profile in p.profiles:
        p.resolve_params(profile)


BAD_PIPELINES = [
    (
        "cycle",
        f"""
     steps:
       a: {{function: "{MOD}:run", inputs: {{x: b}}}}
       b: {{function: "{MOD}:run", inputs: {{x: a}}}}
     """,
        "cycle in step inputs: a -> b -> a",
    ),
    (
        "unknown-input-step",
        f"""
     steps:
       a: {{function: "{MOD}:run", inputs: {{x: nope}}}}
     """,
        "step 'a': input 'x' names unknown step 'nope'",
    ),
    (
        "self-input",
        f"""
     steps:
       a: {{function: "{MOD}:run", inputs: {{x: a}}}}
     """,
        "step 'a': input 'x' is the step itself",
    ),
    (
        "bad-function-spec",
        """
     steps:
       a: {function: "just_a_module"}
     """,
        "step 'a': function must be 'module:callable', got 'just_a_module'",
    ),
    (
        "unknown-step-key",
        f"""
     steps:
       a: {{function: "{MOD}:run", param: {{n: 1}}}}
     """,
        "step 'a': unknown key(s) param",
    ),
    (
        "unknown-top-key",
        f"""
     stages:
       a: {{function: "{MOD}:run"}}
     """,
        "unknown top-level key(s): stages",
    ),
    ("no-steps", "version: 1\n", "'steps' must be a non-empty mapping of step name -> step"),
    (
        "bad-version",
        f"""
     version: 2
     steps:
       a: {{function: "{MOD}:run"}}
     """,
        "unsupported pipeline version 2 (expected 1)",
    ),
    (
        "reserved-output",
        f"""
     steps:
       a: {{function: "{MOD}:run", outputs: [manifest.json]}}
     """,
        "step 'a': output 'manifest.json' must be a relative file name "
        "(not absolute, no '..', not manifest.json)",
    ),
    (
        "escaping-output",
        f"""
     steps:
       a: {{function: "{MOD}:run", outputs: [../x.txt]}}
     """,
        "step 'a': output '../x.txt' must be a relative file name (not absolute, no '..', not manifest.json)",
    ),
    (
        "bad-step-name",
        f"""
     steps:
       my-step: {{function: "{MOD}:run"}}
     """,
        "step name 'my-step' must be an identifier (letters, digits, _)",
    ),
    (
        "profile-unknown-param",
        f"""
     steps:
       a: {{function: "{MOD}:run", params: {{n: 1}}}}
     profiles:
       fast: {{a: {{m: 2}}}}
     """,
        "profile 'fast': step 'a' has no param 'm' (params: n)",
    ),
    (
        "profile-wrong-type",
        f"""
     steps:
       a: {{function: "{MOD}:run", params: {{n: 1}}}}
     profiles:
       fast: {{a: {{n: "many"}}}}
     """,
        "profile 'fast': a.n: expected int (default 1), got str",
    ),
    (
        "profile-unknown-step",
        f"""
     steps:
       a: {{function: "{MOD}:run"}}
     profiles:
       fast: {{zz: {{n: 2}}}}
     """,
        "profile 'fast': unknown step 'zz' (steps: a)",
    ),
    (
        "invalid-yaml",
        "steps:\n  a: [unclosed\n",
        "invalid YAML at line 3: expected ',' or ']', but got '<stream end>'",
    ),
]


@pytest.mark.parametrize("case,text,message", BAD_PIPELINES, ids=[c[0] for c in BAD_PIPELINES])
def test_malformed_pipeline(tmp_path, step_module, case, text, message):
    path = write(tmp_path, text)
    with pytest.raises(PipelineError) as info:
        load_pipeline(path)
    assert str(info.value) == f"{path}: {message}"


def test_missing_module_and_optional_version(tmp_path, step_module):
    p = load_pipeline(
        write(
            tmp_path,
            f"""
        steps:
          a: {{function: "no_such_module_xyz:run"}}
          b: {{function: "{MOD}_nover:run"}}
        """,
        )
    )
    with pytest.raises(PipelineError, match=r"step 'a': module 'no_such_module_xyz' not found$"):
        step_rules(p.steps["a"], p.path)
    assert step_rules(p.steps["b"], p.path).version is None  # VERSION is an optional override


def test_missing_pipeline_file(tmp_path):
    with pytest.raises(PipelineError) as info:
        load_pipeline(tmp_path / "nope.yaml")
    assert (
        str(info.value) == f"{tmp_path / 'nope.yaml'}: cannot read pipeline file (No such file or directory)"
    )


BAD_OVERRIDES = [
    ({"zz.n": 1}, None, "--set zz.n=1: unknown step 'zz' (steps: a, b, c)"),
    (
        {"b.m": 1},
        None,
        "--set b.m=1: step 'b' has no param 'm' (params: n, rate, flag, name, items, anything)",
    ),
    ({"b.n": "ten"}, None, "--set b.n='ten': expected int (default 3), got str"),
    ({"b.n": True}, None, "--set b.n=True: expected int (default 3), got bool"),
    ({"b.rate": "fast"}, None, "--set b.rate='fast': expected float (default 0.5), got str"),
    ({"b.flag": 1}, None, "--set b.flag=1: expected bool (default False), got int"),
    ({"b.rate": float("nan")}, None, "--set b.rate=nan: must be a finite number"),
    ({"b.rate": "inf"}, None, "--set b.rate='inf': must be a finite number"),
    ({"b.items": 5}, None, "--set b.items=5: expected list (default [1, 2]), got int"),
    ({"b": 5}, None, "--set b=5: expected STEP.PARAM=VALUE"),
    ({}, "turbo", "--profile turbo: unknown profile (profiles: fast, dotted)"),
]


@pytest.mark.parametrize("overrides,profile,message", BAD_OVERRIDES)
def test_bad_overrides(tmp_path, step_module, overrides, profile, message):
    p = load_pipeline(write(tmp_path, GOOD))
    with pytest.raises(PipelineError) as info:
        p.resolve_params(profile, overrides)
    assert str(info.value) == message  # an argument error: no file to name


def test_bad_set_syntax():
    with pytest.raises(PipelineError) as info:
        parse_set_argument("coarse.iterations")
    assert str(info.value) == "--set coarse.iterations: expected STEP.PARAM=VALUE"
    with pytest.raises(PipelineError) as info:
        parse_set_argument("a.b=[1, 2")
    assert str(info.value).startswith("--set a.b=[1, 2: value is not valid YAML (")


def test_a_renamed_step_gets_one_line_naming_the_new_name():
    """The `lora` step is `tune` now: an old --set, --until or remembered override says so, once."""
    p = load_pipeline()
    with pytest.raises(PipelineError) as info:
        p.resolve_params(None, {"lora.steps": 3})
    assert str(info.value).startswith("--set lora.steps=3: step 'lora' is now called 'tune' (")
    assert str(info.value).endswith("write tune instead of lora")
    with pytest.raises(PipelineError, match=r"^--until: step 'lora' is now called 'tune'"):
        p.require_step("lora", "--until", from_file=False)
    assert p.resolve_params(None, {"tune.sd15_steps": 3})["tune"]["sd15_steps"] == 3
