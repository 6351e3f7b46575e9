"""What a new user sees of a run's results (issue 36): the "what you got" block, the outputs folder, the
report's wording, the batch table, the light install and its optional extras."""

from __future__ import annotations

import re
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import tomllib

from go_pipeline.outputs import COPIED, PAPER_TIME_FACTOR, result_lines

REPO = Path(__file__).resolve().parents[1]


def _files(folder: Path, names) -> dict[str, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    for n in names:
        (folder / n).write_text("{}" if n.endswith(".json") else "x")
        out[n] = folder / n
    return out


def test_end_of_run_lists_what_you_got_under_outputs(tmp_path):
    out = tmp_path / "scene" / ".go" / "outputs"
    names = ["model.ply", "model.spz", "report.html", "turntable.gif", "contact_sheet.png", "metrics.json"]
    files = _files(out, names)
    lines = result_lines(SimpleNamespace(), files, "scene", "example", cwd=tmp_path)
    start = next(i for i, line in enumerate(lines) if line.startswith("what you got"))
    assert lines[start] == "what you got, in scene/.go/outputs/:"
    listed = [line.split()[0] for line in lines[start + 1 : start + 1 + len(names)]]
    assert sorted(listed) == sorted(names)
    assert any(
        "--profile paper" in line and f"{PAPER_TIME_FACTOR}x this run's time" in line for line in lines
    )


def test_outputs_publish_the_contact_sheet_and_the_spz():
    assert COPIED["contact_sheet.png"] == ("turntable", "contact_sheet.png")
    assert COPIED["model.spz"] == ("export", "model.spz")


def test_run_total_names_the_one_time_compile():
    from go_pipeline.runner import StepResult, _build_note

    ran = StepResult("coarse", "ran", "k", Path("."), False, 310.8, {"rasterizer_build_s": 140.8})
    cached = StepResult("hull", "cached", "k", Path("."), True, 0.0, {"rasterizer_build_s": 99.0})
    assert _build_note([ran, cached]) == ", of which 141 s the one-time compile of the CPU rasterizer"
    assert _build_note([StepResult("eval", "ran", "k", Path("."), False, 3.0, {})]) == ""


def _report(steps, totals=None) -> dict:
    return {
        "result": {"model": "coarse", "reason": "r", "num_gaussians": 10},
        "totals": {"wall_s": 152.8, "cpu_s": 100.0, "peak_mem_mb": 5.0, **(totals or {})},
        "device": "cpu",
        "metrics": None,
        "versions": {"libraries": {}},
        "steps": steps,
    }


def _step(name, reason=None, version=None, code="0123456789ab"):
    status = "skipped" if reason else "ok"
    return {"name": name, "status": status, "reason": reason, "wall_s": 1.0, "cpu_s": 1.0,
            "peak_mem_mb": 1.0, "device": "cpu", "version": version, "code": code}  # fmt: skip


def test_report_summary_names_the_compile_the_cli_total_includes():
    from go_pipeline.reporting.render import _summary_lines

    lines = _summary_lines(_report([], {"rasterizer_build_s": 140.8}))
    assert any("compiled the CPU rasterizer once (141 s" in line for line in lines)
    assert not any("compiled" in line for line in _summary_lines(_report([])))


def test_report_step_table_single_parentheses_and_a_code_version():
    from go_pipeline.reporting.render import _tables

    reason = "no depth model configured (depth.model_path is empty): the depth loss is off"
    head, rows, _, _ = _tables(_report([_step("depth", reason), _step("eval", version="3")]))
    status = rows[0][head.index("status")]
    assert status == f"skipped: {reason}" and "((" not in status and "))" not in status
    assert rows[0][-1] == "code 0123456789ab" and rows[1][-1] == "3"


def test_report_help_says_one_default_format(capsys):
    from go_pipeline.cli import main

    with pytest.raises(SystemExit):
        main(["report", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "else md" in text and "default: json" not in text and "--open" in text


def test_batch_table_shows_this_batch_time_not_the_cached_artifacts():
    from go_pipeline.reporting.batch import BatchResult, _markdown, aggregate, table_rows

    report = _report([_step("coarse")])
    row = {"scene": "a", "status": "ok", "error": None, "report": report, "batch_wall_s": 7.6, "ran": []}
    result = BatchResult([row], 7.9, {"address": "local", "cluster_cpus": 2.0})
    flat = table_rows(result)
    md = _markdown(flat, aggregate(flat), result)
    head = [c.strip() for c in md.splitlines()[6].strip("|").split("|")]
    cells = [
        c.strip() for c in next(x for x in md.splitlines() if x.startswith("| a |")).strip("|").split("|")
    ]
    assert cells[head.index("this batch s")] == "7.6" and cells[head.index("steps ran")] == "0"
    assert cells[head.index("artifacts' wall s")] == "152.8"


def test_batch_without_ray_says_how_to_install_it(monkeypatch, tmp_path, capsys):
    from go_pipeline.cli import main

    monkeypatch.setitem(sys.modules, "ray", None)  # as if the [ray] extra were not installed
    assert main(["batch", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'go-pipeline[ray]'" in err[0]


def test_batch_sets_ray_auth_mode_before_importing_ray():
    """Ray >= 2.5x warns "Token authentication is enabled" on every local ray.init() unless RAY_AUTH_MODE is
    set, and reads it at import: the batch sets it (token) before importing Ray for a local cluster."""
    pytest.importorskip("ray", reason="needs the [ray] extra: pip install -e '.[ray]'")
    import os
    import subprocess

    code = (
        "import os, sys; from go_pipeline.reporting.batch import import_ray; "
        "assert 'ray' not in sys.modules; import_ray(); print(os.environ.get('RAY_AUTH_MODE'))"
    )
    env = {k: v for k, v in os.environ.items() if k != "RAY_AUTH_MODE"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "token", done.stderr


def test_base_install_leaves_out_the_heavy_optional_stacks():
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    names = {re.split(r"[<>=\[ ]", d, maxsplit=1)[0].lower() for d in project["dependencies"]}
    assert not names & {"diffusers", "transformers", "peft", "ray"}
    extras = project["optional-dependencies"]
    assert {re.split(r"[<>=\[]", d, maxsplit=1)[0] for d in extras["sd15"]} == {
        "diffusers",
        "transformers",
        "peft",
    }
    assert extras["ray"][0].startswith("ray[default]")


def test_missing_extra_is_one_clear_error(monkeypatch):
    from go_core.errors import GoError
    from go_core.extras import require_extra

    monkeypatch.setitem(sys.modules, "peft", None)
    with pytest.raises(
        GoError, match=r"needs the optional package\(s\) peft: pip install 'go-pipeline\[sd15\]'"
    ):
        require_extra("sd15", "the SD1.5 repair")


def test_batch_without_ray_says_how_to_install_it_in_one_line(monkeypatch, capsys, tmp_path):
    from go_pipeline.cli import main

    monkeypatch.setitem(sys.modules, "ray", None)  # as if the [ray] extra were not installed
    assert main(["batch", str(tmp_path)]) == 2
    out = capsys.readouterr()
    assert out.out == ""
    assert out.err.splitlines() == [
        "error: go-pipeline batch (scenes on Ray) needs the optional package(s) ray: "
        "pip install 'go-pipeline[ray]'"
    ]


def test_readme_says_which_tests_skip_on_a_fresh_clone():
    text = " ".join((REPO / "README.md").read_text().split())
    assert "shared data" in text and "skip" in text and "fresh clone" in text


def test_export_formats_param():
    from go_pipeline.steps.params import ExportParams

    from go_core.config import SettingError, check_value

    assert ExportParams().formats == ("ply", "spz")
    assert ExportParams(formats=("spz",)).check() == [
        "export.formats must hold ply (the model the other steps read)"
    ]
    with pytest.raises(SettingError):
        check_value(ExportParams, "formats", ["ply", "gltf"])


def test_another_steps_param_skips_a_step_and_is_in_its_key():
    from go_pipeline.skipping import foreign_param_skip, foreign_params

    rule = {"repair.mode": {"no_repair": "no repair (repair.mode no_repair)"}}
    full = {"repair": {"mode": "full"}, "weights": {}}
    ablation = {"repair": {"mode": "no_repair"}, "weights": {}}
    assert foreign_params(rule, full) == {"repair.mode": "full"}  # in the key (runner._key_for)
    assert foreign_param_skip(rule, full) is None
    assert foreign_param_skip(rule, ablation)["reason"] == "no repair (repair.mode no_repair)"


def test_weights_step_skips_under_the_no_repair_ablation():
    from go_pipeline.steps.registry import declaration

    from go_pipeline.skipping import foreign_param_skip

    rule = declaration("go_pipeline.steps.weights").skip_if_param
    assert foreign_param_skip(rule, {"repair": {"mode": "no_repair"}})["status"] == "skipped"
    assert foreign_param_skip(rule, {"repair": {"mode": "full"}}) is None
