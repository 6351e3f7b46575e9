"""A step's reported CPU time, peak memory and wall time are its own: not those of processes it starts (e.g.
the compiler of a one-time rasterizer build), and not the one-time build itself (recorded apart)."""

from __future__ import annotations

import pytest
from _runner_toy import make_toy_project

from go_pipeline import store
from go_pipeline.runner import run_pipeline

# The "side" step, replaced: it starts a child that holds 400 MB and burns 3 CPU-s (like cc1plus building
# the rasterizer), then spends 3 s in what it books as a one-time rasterizer build.
SIDE = """
import subprocess
import sys
import time
VERSION = "1"

CHILD = '''
import time
block = b"x" * (400 * 2**20)
t = time.process_time()
while time.process_time() - t < 3.0:
    pass
'''

def run(ctx, inputs, params):
    t0 = time.perf_counter()
    from go_core.render.build import BUILD_TIME

    subprocess.run([sys.executable, "-c", CHILD], check=True)
    start = time.perf_counter()
    time.sleep(3.0)
    BUILD_TIME.seconds += time.perf_counter() - start
    (ctx.out_dir / "side.json").write_text("{}")
    ctx.record(work_s=time.perf_counter() - t0, own_cpu_s=time.process_time())
"""


@pytest.mark.parametrize("in_process", [False, True])
def test_step_usage_excludes_child_processes_and_the_one_time_build(tmp_path, in_process):
    toy = make_toy_project(tmp_path)
    toy.step_file("side").write_text(SIDE)
    # a large parent: Linux's ru_maxrss of a child starts from its parent's RSS at the fork
    ballast = b"x" * (600 * 2**20) if not in_process else b""
    result = run_pipeline(toy.scene, pipeline_path=toy.pipeline, quiet=True, in_process=in_process)
    del ballast
    m = store.load_manifest(result.step("side").artifact_dir)
    build, work = m["record"]["rasterizer_build_s"], m["record"]["work_s"]
    assert 3.0 <= build < 5.0
    # the step's wall time is its work (+ process start-up) less the build: had the build been booked, the
    # wall time would exceed the work; the margin is the worker's start-up, which grows with machine load
    assert m["wall_s"] < work - 0.2 * build
    assert m["wall_s"] > work - build - 0.1
    if not in_process:  # in-process, the runner's own footprint is the process's
        assert m["peak_mem_mb"] < 300, "the child's 400 MB or the parent's 600 MB were booked to the step"
        # the worker's own CPU time (imports included, which grow with machine load) as the step saw it; the
        # child's 3 CPU-s would come on top
        own = m["record"]["own_cpu_s"]
        assert own - 0.1 < m["cpu_s"] < own + 1.5, "the child's CPU time was booked to the step"
    other = store.load_manifest(result.step("double").artifact_dir)
    assert "rasterizer_build_s" not in other["record"]
