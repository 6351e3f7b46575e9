"""How libgomp's wait policy changes the speed of a coarse training iteration, on an idle machine and beside
busy processes.

Every parallel region (each compiled kernel, and each torch op on more than 32k elements) must wake the
team's sleeping threads; with ``OMP_WAIT_POLICY=PASSIVE`` they sleep at once, and on a VM a wake-up of an
idle vCPU can cost far more than the work of a small op. Spinning first bridges the short gaps between the
~80 regions of an iteration, but a long spin burns the time slice that a competing process needs. This
script measures the trade-off: each setting runs in a fresh process (libgomp reads its environment once),
the settings alternate in rounds so that machine drift hits them alike, and ``--busy K`` starts K
pure-Python busy loops beside them.

    python benchmarks/archive/omp_wait.py --busy 0 1 --rounds 3 --json benchmarks/results/omp_wait.json

Workload: the visual hull of a dev scene (20k Gaussians) trained with the coarse loss, densification off, SH
degree 2 from the third iteration; per-iteration wall time (median after a warm-up) and the CPU cores used.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from _machine import cpu_name  # benchmarks/ is on sys.path when run as a script

DEV = Path(__file__).resolve().parents[3] / "shared" / "data" / "dev"
SETTINGS = {  # name: environment for libgomp (None = leave the variable unset)
    "passive": {"OMP_WAIT_POLICY": "PASSIVE", "GOMP_SPINCOUNT": None},
    "spin1000": {"OMP_WAIT_POLICY": None, "GOMP_SPINCOUNT": "1000"},
    "spin3000": {"OMP_WAIT_POLICY": None, "GOMP_SPINCOUNT": "3000"},
    "libgomp_default": {"OMP_WAIT_POLICY": None, "GOMP_SPINCOUNT": None},
    "one_thread": {"OMP_WAIT_POLICY": "PASSIVE", "GOMP_SPINCOUNT": None, "GO_BENCH_THREADS": "1"},
}


def child(scene_dir: Path, iterations: int, warmup: int) -> dict:
    """Train and time in this process (its libgomp settings came from the environment)."""
    import torch

    from go_core.coarse.hull import points_to_gaussians, visual_hull
    from go_core.coarse.loop import CoarseConfig, NoDensify, TrainView, optimize
    from go_core.scene.loader import load_scene

    torch.set_num_threads(int(os.environ.get("GO_BENCH_THREADS", "2")))
    scene = load_scene(scene_dir)
    cams = scene.train_cameras
    masks = [v.mask for v in scene.train]
    hull = visual_hull(
        cams, masks, [v.image for v in scene.train], num_points=20_000, all_but_one=False, seed=0
    )
    init = points_to_gaussians(hull.points, hull.colors, opacity=0.1)
    views = [TrainView.from_arrays(v.camera, v.image, m) for v, m in zip(scene.train, masks, strict=True)]
    config = CoarseConfig(iterations=iterations, floaters=False, sh_increase_every=1)
    marks: list[tuple[float, float]] = []

    def tick(step: int, info: dict) -> None:
        marks.append((time.perf_counter(), time.process_time()))

    optimize(
        init,
        views,
        config,
        generator=torch.Generator().manual_seed(0),
        strategy=NoDensify(),
        on_progress=tick,
    )
    steps = list(itertools.pairwise(marks[warmup:]))
    wall = [b[0] - a[0] for a, b in steps]
    cpu = [b[1] - a[1] for a, b in steps]
    return {
        "ms_per_iteration": round(1e3 * statistics.median(wall), 3),
        "cores_used": round(sum(cpu) / sum(wall), 3),
        "threads": torch.get_num_threads(),
        "gaussians": len(init),
    }


def run_setting(name: str, args) -> dict:
    env = dict(os.environ)
    for key, value in SETTINGS[name].items():
        if value is None:
            env.pop(key, None)
        else:
            env[key] = value
    cmd = [
        sys.executable,
        __file__,
        "--child",
        "--scene",
        str(args.scene),
        "--iterations",
        str(args.iterations),
        "--warmup",
        str(args.warmup),
    ]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, default=DEV / "milk")
    ap.add_argument("--iterations", type=int, default=200)
    ap.add_argument("--warmup", type=int, default=30)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--busy", type=int, nargs="*", default=[0, 1], help="competing busy processes")
    ap.add_argument("--settings", nargs="*", default=list(SETTINGS), choices=list(SETTINGS))
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.scene, args.iterations, args.warmup)))
        return 0

    rows = []
    for busy in args.busy:
        hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
        try:
            runs: dict[str, list[dict]] = {name: [] for name in args.settings}
            for _ in range(args.rounds):
                for name in args.settings:
                    runs[name].append(run_setting(name, args))
        finally:
            for h in hogs:
                h.kill()
                h.wait()
        for name, results in runs.items():
            times = [r["ms_per_iteration"] for r in results]
            row = {
                "busy_processes": busy,
                "setting": name,
                "environment": dict(SETTINGS[name]),
                "ms_per_iteration_median": round(statistics.median(times), 2),
                "ms_per_iteration_runs": times,
                "cores_used": round(statistics.median(r["cores_used"] for r in results), 2),
                "gaussians": results[0]["gaussians"],
            }
            rows.append(row)
            print(
                f"busy={busy} {name:16s} {row['ms_per_iteration_median']:8.2f} ms/it  runs "
                f"{row['ms_per_iteration_runs']}  cores {row['cores_used']}"
            )
    if args.json:
        payload = {
            "benchmark": "omp_wait",
            "cpu": cpu_name(),
            "cpu_count": os.cpu_count(),
            "scene": args.scene.name,
            "iterations": args.iterations,
            "warmup": args.warmup,
            "rounds": args.rounds,
            "results": rows,
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(payload, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
