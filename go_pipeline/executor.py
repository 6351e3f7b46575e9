"""Run one step function: in a child process (default) or in this process (``in_process=True``: for
debuggers; CPU time and peak memory are then those of the whole process)."""

from __future__ import annotations

import json
import logging
import os
import resource
import subprocess
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field
from typing import Any

from go_core.errors import GoError
from go_pipeline.display import Display
from go_pipeline.openmp import set_default_wait
from go_pipeline.worker import rasterizer_build_seconds


@dataclass
class Execution:
    ok: bool
    wall_s: float
    cpu_s: float
    peak_mem_mb: float
    device: str = "cpu"
    records: dict[str, Any] = field(default_factory=dict)
    error_kind: str = ""  # "go" (a GoError: one line for the user) | "crash" | "killed"
    error_type: str = ""
    error_message: str = ""
    traceback: str = ""


def execute(
    spec: dict[str, Any], display: Display, in_process: bool = False, keep_fds: tuple[int, ...] = ()
) -> Execution:
    if in_process:
        return _execute_here(spec, display)
    return _execute_child(spec, display, keep_fds)


def _execute_here(spec: dict[str, Any], display: Display) -> Execution:
    from go_pipeline.worker import run_step_in_process

    records: dict[str, Any] = {}

    class _Direct:
        def send(self, event: dict[str, Any]) -> None:
            display.handle(event, records)

    log = logging.getLogger(f"go_pipeline.step.{spec['step']}.{id(records)}")
    log.setLevel(logging.DEBUG)
    log.propagate = False
    from go_pipeline.context import SinkLogHandler

    handler = SinkLogHandler(_Direct())
    log.addHandler(handler)
    t0, c0, b0 = time.perf_counter(), time.process_time(), rasterizer_build_seconds()
    try:
        ctx = run_step_in_process(spec, _Direct(), log)
        ok, kind, etype, msg, tb, device = True, "", "", "", "", ctx.resolved_device()
    except GoError as e:
        ok, kind, etype, msg, tb, device = (
            False,
            "go",
            type(e).__name__,
            str(e),
            traceback.format_exc(),
            "cpu",
        )
    except Exception as e:  # noqa: BLE001
        ok, kind, etype, msg, tb, device = (
            False,
            "crash",
            type(e).__name__,
            str(e),
            traceback.format_exc(),
            "cpu",
        )
    finally:
        log.removeHandler(handler)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    wall = _set_apart_build(time.perf_counter() - t0, rasterizer_build_seconds() - b0, spec, display, records)
    return Execution(ok, wall, time.process_time() - c0, peak, device, records, kind, etype, msg, tb)


def _set_apart_build(
    wall: float, build_s: float, spec: dict[str, Any], display: Display, records: dict[str, Any]
) -> float:
    """The step's wall time without the one-time C++ build of the rasterizer it triggered (recorded apart)."""
    if build_s <= 0:
        return wall
    records["rasterizer_build_s"] = round(build_s, 2)
    display.log.info(
        f"[{spec['step']}] built the CPU rasterizer (once per machine and source version) in "
        f"{build_s:.0f} s; recorded as record.rasterizer_build_s, not counted in the step's wall time"
    )
    return max(wall - build_s, 0.0)


def _child_env() -> dict[str, str]:
    """The step worker's environment: this process's, with the worker's fixed settings."""
    env = dict(os.environ)
    set_default_wait(env)  # libgomp reads it when torch loads it: in the child's environment
    env.setdefault("PYTHONUNBUFFERED", "1")
    env["PYTHONSAFEPATH"] = "1"  # processes the step starts (multiprocessing) never import from their cwd
    return env


def _start_readers(
    proc: subprocess.Popen,
    read_fd: int,
    spec: dict[str, Any],
    display: Display,
    records: dict[str, Any],
    outcome: dict[str, Any],
) -> list[threading.Thread]:
    """Threads that pass the worker's events to ``display`` (its final event into ``outcome``) and its
    output to the debug log."""

    def read_events() -> None:
        with os.fdopen(read_fd, encoding="utf-8") as f:
            for line in f:
                try:
                    event = json.loads(line)
                except ValueError:
                    continue
                if event.get("type") in ("done", "error"):
                    outcome.update(event)
                else:
                    display.handle(event, records)

    def read_output() -> None:
        assert proc.stdout is not None
        for raw in proc.stdout:
            text = raw.decode("utf-8", "replace").rstrip()
            if text:
                display.log.log(
                    logging.INFO if display.debug else logging.DEBUG, f"[{spec['step']}] (output) {text}"
                )

    threads = [
        threading.Thread(target=read_events, daemon=True),
        threading.Thread(target=read_output, daemon=True),
    ]
    for t in threads:
        t.start()
    return threads


def _execute_child(spec: dict[str, Any], display: Display, keep_fds: tuple[int, ...]) -> Execution:
    records: dict[str, Any] = {}
    outcome: dict[str, Any] = {}
    read_fd, write_fd = os.pipe()
    oom_before = _oom_kills()
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        worker_command(write_fd),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        pass_fds=(write_fd, *keep_fds),
        env=_child_env(),
    )
    os.close(write_fd)
    threads = _start_readers(proc, read_fd, spec, display, records, outcome)
    try:
        assert proc.stdin is not None
        proc.stdin.write(json.dumps(spec).encode("utf-8"))
        proc.stdin.close()
    except BrokenPipeError:
        pass
    try:
        _, status, usage = os.wait4(proc.pid, 0)
    except BaseException:
        proc.kill()
        os.wait4(proc.pid, 0)
        proc.returncode = -9
        raise
    proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    for t in threads:
        t.join(timeout=5)
    # wait4 covers the child's own children too (e.g. the compiler of a one-time rasterizer build) and its
    # ru_maxrss starts from this process's RSS at the fork: prefer the figures the child measured of itself
    cpu = float(outcome.get("self_cpu_s", usage.ru_utime + usage.ru_stime))
    peak = float(outcome.get("self_peak_mb", usage.ru_maxrss / 1024.0))  # ru_maxrss: KiB on Linux
    wall = _set_apart_build(wall, float(outcome.get("build_s", 0.0)), spec, display, records)
    if proc.returncode == 0 and outcome.get("type") == "done":
        return Execution(True, wall, cpu, peak, outcome.get("device", "cpu"), records)
    if outcome.get("type") == "error":
        failure = (outcome["kind"], outcome["exc_type"], outcome["message"], outcome.get("traceback", ""))
    else:
        failure = ("killed", "ProcessDied", death_message(proc.returncode, _oom_kills() > oom_before))
    return Execution(False, wall, cpu, peak, "cpu", records, *failure)


def worker_command(event_fd: int) -> list[str]:
    """The step worker's command line. The current directory must not shadow the package: with ``-m`` a
    scene folder carrying ``go_pipeline/worker.py`` would run its own code (``-P``: Python 3.11+; 3.10
    drops the cwd entry before importing anything)."""
    if sys.version_info >= (3, 11):
        return [sys.executable, "-P", "-m", "go_pipeline.worker", str(event_fd)]
    bootstrap = (
        "import sys; sys.path[:] = [p for p in sys.path if p not in ('', '.')]; "
        "from go_pipeline.worker import main; sys.exit(main())"
    )
    return [sys.executable, "-c", bootstrap, str(event_fd)]


def death_message(returncode: int, oom_killed: bool = False) -> str:
    """What ended a step process that reported nothing: a signal (named) or an exit code."""
    import signal

    if returncode >= 0:
        return f"the step process exited with code {returncode} without reporting a result"
    number = -returncode
    try:
        name = signal.Signals(number).name
    except ValueError:
        name = "unknown signal"
    why = " by the kernel's out-of-memory killer" if oom_killed else ""
    return f"the step process was killed{why} by signal {number} ({name})"


def _oom_kills() -> int:
    """The cgroup's count of out-of-memory kills (cgroup v2 ``memory.events``), 0 where unreadable."""
    try:
        for line in open("/sys/fs/cgroup/memory.events", encoding="ascii"):
            if line.startswith("oom_kill "):
                return int(line.split()[1])
    except (OSError, ValueError):
        pass
    return 0
