"""Chaos test of resumption: SIGKILL `go-pipeline run` at random moments, resume, and check that every
resumed run ends with artifacts byte-identical to an uninterrupted run (every file of every step's current
artifact, metrics.json included; manifests are compared by their content hash, since they hold timings).

Kills alternate between the whole process group (like closing the terminal) and the step worker only (the
CLI sees its child die, reports it and exits; the rerun resumes from the step's checkpoints). A trial is a
fresh copy of the example scene killed ``--kills-per-trial`` times, then resumed to the end; trials repeat
until ``--kills`` kills have landed while a run was in progress.

    nice -n 10 python benchmarks/archive/chaos.py --kills 20 --out benchmarks/results/chaos_example.json

The CPU rasterizer is built first (a kill during the build is tests/test_build.py's job).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from _machine import cpu_name


def artifact_files(workdir: Path) -> dict[str, str]:
    """'step/file' -> sha256 for every file of every step's current artifact (manifest.json excluded:
    it holds timings; its content_hash and outputs are checked through these files)."""
    from go_pipeline import store

    found: dict[str, str] = {}
    for step, manifest in sorted(store.current_manifests(workdir).items()):
        folder = store.artifact_dir(workdir, step)
        for rel in sorted(manifest["outputs"]):
            found[f"{step}/{rel}"] = hashlib.sha256((folder / rel).read_bytes()).hexdigest()
    return found


def cli(scene: Path, args: list[str]) -> list[str]:
    return [sys.executable, "-m", "go_pipeline.cli", "run", str(scene), "--quiet", *args]


def worker_pids(cli_pid: int) -> list[int]:
    """The step worker processes started by the CLI process ``cli_pid``."""
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            if ppid == cli_pid and b"go_pipeline.worker" in (entry / "cmdline").read_bytes():
                pids.append(int(entry.name))
        except (OSError, ValueError, IndexError):
            continue
    return pids


def run_to_end(scene: Path, args: list[str], timeout: float) -> tuple[int, float, str]:
    t0 = time.perf_counter()
    done = subprocess.run(cli(scene, args), capture_output=True, text=True, timeout=timeout)
    return done.returncode, time.perf_counter() - t0, done.stderr


def kill_once(scene: Path, args: list[str], delay: float, mode: str) -> dict[str, Any]:
    """Start a run, SIGKILL it (group or worker) after ``delay`` s; what happened."""
    proc = subprocess.Popen(
        cli(scene, args), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True
    )
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < delay and proc.poll() is None:
        time.sleep(0.02)
    event: dict[str, Any] = {"delay_s": round(delay, 2), "mode": mode}
    if proc.poll() is not None:
        event["landed"] = False  # the run had finished: no kill
        proc.communicate()
        return event
    used = mode
    if mode == "worker":
        pids = worker_pids(proc.pid)
        if pids:
            for pid in pids:
                os.kill(pid, signal.SIGKILL)
        else:
            used = "group (no worker running)"
            os.killpg(proc.pid, signal.SIGKILL)
    else:
        os.killpg(proc.pid, signal.SIGKILL)
    _, err = proc.communicate(timeout=120)
    try:  # the group may hold stragglers (a worker the CLI had not reaped)
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    event.update(landed=True, mode=used, exit=proc.returncode)
    if mode == "worker":
        event["cli_said"] = (err.decode("utf-8", "replace").strip().splitlines() or [""])[-1][:200]
    return event


def _count_modes(events: list[dict[str, Any]]) -> dict[str, int]:
    return {m: sum(e["mode"] == m for e in events) for m in sorted({e["mode"] for e in events})}


def summarize(opts, ref_wall: float, reference: dict, trials: list, cpu0) -> dict[str, Any]:
    """The result so far, written to ``--out`` (after every trial, so a cut-off run leaves its figures)."""
    cpu1 = os.times()
    events = [e for t in trials for e in t["kills"] if e.get("landed")]
    result = {
        "command": "python benchmarks/archive/chaos.py " + " ".join(sys.argv[1:]),
        "profile": opts.profile,
        "overrides": opts.sets,
        "cpu": cpu_name(),
        "note": opts.note,
        "reference_wall_s": round(ref_wall, 1),
        "reference_files": len(reference),
        "kills_landed": len(events),
        "kills_by_mode": {
            m: sum(e["mode"] == m for e in events) for m in sorted({e["mode"] for e in events})
        },
        "trials": len(trials),
        "all_identical": all(t["identical"] for t in trials),
        "children_cpu_s": round(
            (cpu1.children_user - cpu0.children_user) + (cpu1.children_system - cpu0.children_system), 1
        ),
        "trial_results": trials,
    }
    opts.out.parent.mkdir(parents=True, exist_ok=True)
    opts.out.write_text(json.dumps(result, indent=2) + "\n")
    return result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=20, help="SIGKILLs that must land mid-run (default 20)")
    ap.add_argument("--kills-per-trial", type=int, default=5)
    ap.add_argument("--profile", default="example")
    ap.add_argument("--set", dest="sets", action="append", default=[], help="extra --set STEP.PARAM=V")
    ap.add_argument("--seed", type=int, default=0, help="seed of the kill schedule")
    ap.add_argument("--root", type=Path, help="work folder (default: a temp dir, removed)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--note", default="", help="what else ran on the machine (recorded in the JSON)")
    opts = ap.parse_args()

    from go_pipeline.resources import example_scene_path

    subprocess.run([sys.executable, "-m", "go_core.render.build"], check=True)
    root = opts.root or Path(tempfile.mkdtemp(prefix="go-chaos-"))
    root.mkdir(parents=True, exist_ok=True)
    args = ["--profile", opts.profile] + [x for s in opts.sets for x in ("--set", s)]
    rng = random.Random(opts.seed)
    cpu0 = os.times()

    ref_scene = root / "scene"  # every trial runs in this same folder (artifacts may name their scene)
    shutil.rmtree(ref_scene, ignore_errors=True)
    shutil.copytree(example_scene_path(), ref_scene)
    code, ref_wall, err = run_to_end(ref_scene, args, timeout=3600)
    if code != 0:
        raise SystemExit(f"the uninterrupted reference run failed:\n{err}")
    reference = artifact_files(ref_scene / ".go")
    print(f"reference: {len(reference)} files, {ref_wall:.1f} s", flush=True)
    shutil.rmtree(ref_scene)

    trials: list[dict[str, Any]] = []
    landed = 0
    modes = ["group", "worker"]
    while landed < opts.kills:
        scene = ref_scene
        shutil.rmtree(scene, ignore_errors=True)
        shutil.copytree(example_scene_path(), scene)
        events = []
        remaining = ref_wall  # what is left of the run, roughly: a resumed run skips what is done
        for _ in range(opts.kills_per_trial):
            if landed >= opts.kills:
                break
            delay = rng.uniform(0.5, max(0.8 * remaining, 2.0))  # a random moment of what is left
            event = kill_once(scene, args, delay, modes[landed % 2])
            events.append(event)
            print(f"trial {len(trials)}: {event}", flush=True)
            if not event.get("landed"):
                break  # the run finished before the kill: this trial is done
            landed += 1
            remaining = max(remaining - 0.7 * delay, 2.0)
        code, wall, err = run_to_end(scene, args, timeout=3600)  # resume to the end (a no-op if done)
        files = artifact_files(scene / ".go") if code == 0 else {}
        differ = sorted(k for k in set(reference) | set(files) if reference.get(k) != files.get(k))
        trial = {
            "kills": events,
            "resume_exit": code,
            "resume_wall_s": round(wall, 1),
            "files": len(files),
            "identical": code == 0 and not differ,
            "differing_files": differ,
        }
        if code != 0:
            trial["resume_error"] = err.strip().splitlines()[-1:] if err.strip() else []
        trials.append(trial)
        print(f"trial {len(trials) - 1}: identical={trial['identical']} ({len(files)} files)", flush=True)
        summarize(opts, ref_wall, reference, trials, cpu0)

    result = summarize(opts, ref_wall, reference, trials, cpu0)
    print(json.dumps({k: v for k, v in result.items() if k != "trial_results"}, indent=2))
    if not opts.root:
        shutil.rmtree(root, ignore_errors=True)
    return 0 if result["all_identical"] else 1


if __name__ == "__main__":
    sys.exit(main())
