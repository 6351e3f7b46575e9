"""Steps run with a short OpenMP spin unless the user chose a wait policy (go_pipeline/openmp.py)."""

from __future__ import annotations

import json

import pytest
from _runner_toy import make_toy_project

from go_pipeline.openmp import SPIN_COUNT, set_default_wait
from go_pipeline.runner import run_pipeline

# The "side" step, replaced: it records the libgomp variables its process started with.
SIDE = """
import json
import os
VERSION = "1"

def run(ctx, inputs, params):
    seen = {k: os.environ.get(k) for k in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    (ctx.out_dir / "side.json").write_text(json.dumps(seen))
"""


@pytest.mark.parametrize(
    ("given", "expected"),
    [
        ({}, {"GOMP_SPINCOUNT": SPIN_COUNT}),
        ({"OMP_WAIT_POLICY": "PASSIVE"}, {"OMP_WAIT_POLICY": "PASSIVE"}),
        ({"OMP_WAIT_POLICY": "active"}, {"OMP_WAIT_POLICY": "active"}),
        ({"GOMP_SPINCOUNT": "0"}, {"GOMP_SPINCOUNT": "0"}),
    ],
)
def test_short_spin_only_when_the_user_chose_nothing(given, expected):
    env = {"PATH": "/bin", **given}
    set_default_wait(env)
    assert env == {"PATH": "/bin", **expected}


@pytest.mark.parametrize("user_policy", [None, "PASSIVE"])
def test_step_processes_start_with_the_spin_setting(tmp_path, monkeypatch, user_policy):
    monkeypatch.delenv("GOMP_SPINCOUNT", raising=False)
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    if user_policy:
        monkeypatch.setenv("OMP_WAIT_POLICY", user_policy)
    toy = make_toy_project(tmp_path)
    toy.step_file("side").write_text(SIDE)
    result = run_pipeline(toy.scene, pipeline_path=toy.pipeline, quiet=True)
    seen = json.loads((result.step("side").artifact_dir / "side.json").read_text())
    if user_policy:
        assert seen == {"OMP_WAIT_POLICY": user_policy, "GOMP_SPINCOUNT": None}
    else:
        assert seen == {"OMP_WAIT_POLICY": None, "GOMP_SPINCOUNT": SPIN_COUNT}
