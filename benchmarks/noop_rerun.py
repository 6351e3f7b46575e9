"""Benchmark: a second ``go-pipeline run`` of a finished scene does no work and returns in <= 2 s.

Runs the pipeline once to completion (the built-in example by default), then times ``--repeats`` fresh
``go-pipeline run`` processes (the installed console script, interpreter start-up included) and checks
that each ran no step. Prints the figures and writes them as JSON.

    python benchmarks/noop_rerun.py                      # the built-in example (first run: minutes)
    python benchmarks/noop_rerun.py --scene DIR [--pipeline FILE] [--set step.param=value ...]
    python benchmarks/noop_rerun.py --toy                # the tests' toy pipeline (seconds; for development)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

LIMIT_S = 2.0
REPO = Path(__file__).resolve().parents[1]


def cli_command() -> list[str]:
    exe = shutil.which("go-pipeline")
    return [exe] if exe else [sys.executable, "-m", "go_pipeline.cli"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", help="scene folder (default: the built-in example, copied to --workdir)")
    ap.add_argument("--workdir", help="work folder (default: a temp dir)")
    ap.add_argument("--pipeline", help="pipeline.yaml (default: the packaged one)")
    ap.add_argument("--profile", help="profile (default: example for the built-in example)")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="STEP.PARAM=VALUE")
    ap.add_argument("--until", metavar="STEP", help="pass --until STEP to go-pipeline run")
    ap.add_argument(
        "--toy", action="store_true", help="use the tests' toy pipeline instead of the real steps"
    )
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default="noop_rerun.json", help="JSON results file")
    args = ap.parse_args(argv)

    work = Path(args.workdir or tempfile.mkdtemp(prefix="go-noop-")).resolve()
    env = dict(os.environ)
    extra: list[str] = []
    if args.toy:
        sys.path.insert(0, str(REPO / "tests"))
        from _runner_toy import make_toy_project

        toy = make_toy_project(work)
        env = toy.env()
        target = ["run", str(toy.scene), "--pipeline", str(toy.pipeline)]
        label = "toy pipeline"
    elif args.scene:
        target = ["run", str(Path(args.scene).resolve())]
        label = str(args.scene)
    else:
        target = ["run", "--example", "--workdir", str(work)]
        label = "built-in example"
    if args.pipeline:
        extra += ["--pipeline", args.pipeline]
    if args.profile:
        extra += ["--profile", args.profile]
    if args.until:
        extra += ["--until", args.until]
    for s in args.sets:
        extra += ["--set", s]
    cmd = cli_command() + target + extra

    print(f"first run ({label}): {' '.join(cmd)}", flush=True)
    t0 = time.perf_counter()
    first = subprocess.run(cmd, env=env)
    first_s = time.perf_counter() - t0
    if first.returncode != 0:
        print(f"first run failed with exit code {first.returncode}", file=sys.stderr)
        return 1

    times: list[float] = []
    did_work = False
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        again = subprocess.run(cmd, env=env, capture_output=True, text=True)
        times.append(time.perf_counter() - t0)
        if again.returncode != 0:
            print(again.stderr, file=sys.stderr)
            return 1
        did_work |= " running " in again.stderr or " ran " in again.stderr
    result = {
        "benchmark": "noop_rerun",
        "scene": label,
        "command": cmd,
        "first_run_s": round(first_s, 3),
        "noop_runs_s": [round(t, 4) for t in times],
        "noop_median_s": round(statistics.median(times), 4),
        "noop_max_s": round(max(times), 4),
        "limit_s": LIMIT_S,
        "did_work": did_work,
        "passed": max(times) <= LIMIT_S and not did_work,
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "node": platform.node()},
    }
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(
        f"no-op rerun: median {result['noop_median_s']:.3f} s, max {result['noop_max_s']:.3f} s over "
        f"{len(times)} runs (limit {LIMIT_S} s); steps re-run: {'yes' if did_work else 'none'} -> "
        f"{'PASS' if result['passed'] else 'FAIL'}  [{args.out}]"
    )
    return 0 if result["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
