"""Child-process entry point that runs one step: ``python -P -m go_pipeline.worker EVENT_FD < spec.json``
(``-P``: the current directory, e.g. a scene folder, cannot shadow the package; see executor.worker_command).

Running each step in its own process gives an honest per-step peak memory and CPU time (measured by the
child itself, see ``own_usage``; ``os.wait4`` in the parent is the fallback) and returns the step's memory
to the OS afterwards. The child dies with its parent (PR_SET_PDEATHSIG), so a killed CLI never leaves a step
writing into the work dir.
"""

from __future__ import annotations

import ctypes
import importlib
import json
import logging
import os
import resource
import signal
import sys
import threading
import time
import traceback
from pathlib import Path

EXIT_OK = 0
EXIT_GO_ERROR = 3
EXIT_CRASH = 4


def _die_with_parent(parent_pid: int) -> None:
    """Ask the kernel to SIGKILL us when the parent dies; a watchdog thread covers the race before."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent_pid:
        os._exit(EXIT_CRASH)

    def watch() -> None:
        while True:
            time.sleep(0.5)
            if os.getppid() != parent_pid:
                os._exit(EXIT_CRASH)

    threading.Thread(target=watch, daemon=True, name="parent-watchdog").start()


def run_step_in_process(spec: dict, sink, log: logging.Logger):
    """Import the step function and call it with a fresh context; returns the context."""
    from go_pipeline.context import RunnerStepContext

    ctx = RunnerStepContext(
        spec["step"],
        Path(spec["out_dir"]),
        Path(spec["checkpoint_dir"]),
        spec["seed"],
        spec["device"],
        sink,
        log,
    )
    module = importlib.import_module(spec["module"])
    fn = getattr(module, spec["callable"], None)
    if not callable(fn):
        from go_core.errors import PipelineError

        raise PipelineError(
            f"step {spec['step']!r}: {spec['module']} has no callable {spec['callable']!r}",
            spec.get("pipeline_path"),
        )
    inputs = {name: Path(p) for name, p in spec["inputs"].items()}
    from go_pipeline.pipeline import step_params

    fn(ctx, inputs, step_params(spec["module"], spec["params"]))
    return ctx


LIBRARY_LOGGERS = ("go_core.render.build",)  # one-time notices (e.g. "compiling once") for the user


def library_notices(handler: logging.Handler) -> None:
    """Route the INFO lines of ``LIBRARY_LOGGERS`` to the run log and console, like the step's own."""
    for name in LIBRARY_LOGGERS:
        logger = logging.getLogger(name)
        logger.setLevel(logging.INFO)
        logger.propagate = False
        for old in list(logger.handlers):
            logger.removeHandler(old)
        logger.addHandler(handler)


def rasterizer_build_seconds() -> float:
    """Seconds this process spent compiling the CPU rasterizer (0 if it never loaded it)."""
    build = sys.modules.get("go_core.render.build")
    return float(build.BUILD_TIME.seconds) if build is not None else 0.0


def own_usage() -> dict[str, float]:
    """CPU seconds and peak memory of this process alone, and the one-time rasterizer build time in it.

    The parent's wait4 figures also cover this process's children: a step that triggers the one-time C++
    build of the rasterizer would otherwise report the compiler's ~1.5 GB and CPU time as its own. The CPU
    time of the step's own worker processes (loo's parallel runs) counts, unless the build ran in it.
    """
    usage = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    build_s = rasterizer_build_seconds()
    workers_cpu = 0.0 if build_s > 0 else children.ru_utime + children.ru_stime
    return {
        "self_cpu_s": usage.ru_utime + usage.ru_stime + workers_cpu,
        "self_peak_mb": _peak_rss_mb(usage),
        "build_s": build_s,
    }


def _peak_rss_mb(usage) -> float:
    """Peak resident memory of this process image. Linux's VmHWM starts afresh at exec; ru_maxrss does not:
    it keeps the high-water mark of the image the process was started from (the parent's RSS at fork/vfork,
    e.g. a 1 GB test runner), so it is only the fallback."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return usage.ru_maxrss / 1024.0  # KiB on Linux


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    event_fd = int(argv[0])
    spec = json.loads(sys.stdin.read())
    _die_with_parent(int(spec["parent_pid"]))
    wanted = [p for p in spec.get("sys_path", []) if p]
    sys.path[:] = wanted + [p for p in sys.path if p not in wanted]  # the parent's import path

    from go_pipeline.context import PipeSink, SinkLogHandler

    sink = PipeSink(event_fd)
    log = logging.getLogger(f"go_pipeline.step.{spec['step']}")
    log.setLevel(logging.DEBUG)
    log.propagate = False
    log.addHandler(SinkLogHandler(sink))
    library_notices(SinkLogHandler(sink))
    try:
        ctx = run_step_in_process(spec, sink, log)
        sink.send({"type": "done", "device": ctx.resolved_device(), **own_usage()})
        code = EXIT_OK
    except KeyboardInterrupt:
        code = 130
    except BaseException as e:  # noqa: BLE001 - everything is reported to the parent
        from go_core.errors import GoError

        is_go = isinstance(e, GoError)
        sink.send(
            {
                "type": "error",
                "kind": "go" if is_go else "crash",
                "exc_type": type(e).__name__,
                "message": str(e),
                "traceback": traceback.format_exc(),
                **own_usage(),
            }
        )
        code = EXIT_GO_ERROR if is_go else EXIT_CRASH
    sys.stdout.flush()
    sys.stderr.flush()
    sink.close()
    return code


if __name__ == "__main__":
    sys.exit(main())
