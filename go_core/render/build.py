"""Build once per machine and load the compiled CPU rasterizer (`python -m go_core.render.build` prebuilds).

The extension (the rasterizer from go_core/render/csrc, and the kernels that are not rendering from
go_core/kernels/csrc: the fused Adam step and the loss terms ``go_core.coarse.losses`` reaches through
``torch.ops.go_ssim``) is compiled with the system C++ compiler through ``torch.utils.cpp_extension.load``
(the pinned PyPI ninja). The build directory is keyed by a hash of the sources and their
folder, flags, torch/python/ninja versions and the CPU's instruction-set flags (the code is built with
``-march=native``), under ``$TORCH_EXTENSIONS_DIR`` if set, else ``~/.cache/go-pipeline/torch_extensions``.
Later calls only load it.

Builds survive kills and share a folder safely:
* one build tool: the ``ninja`` of the PyPI package (a pinned dependency), put first on PATH for the build;
  another ninja (e.g. Debian's) records builds differently and would decide each build is stale;
* every build holds ``go-build.lock`` (an ``fcntl`` lock the kernel drops when its holder dies, holding the
  holder's pid); whoever gets it and finds torch's own ``lock`` file knows that file's owner is gone (a
  SIGKILL mid-build leaves it, and torch would wait on it forever) and removes it with a message;
* a "compiling once" line comes before any compilation, and the seconds spent building are recorded in
  ``BUILD_TIME`` (the runner keeps them out of a step's time).
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import hashlib
import logging
import os
import platform
import shutil
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)

HERE = Path(__file__).resolve().parent
CSRC = HERE / "csrc"  # the rasterizer (projection, binning, compositing) and the shared vector header
# Every file the extension is built from, relative to this folder: the rasterizer and the kernels that are
# not rendering (go_core/kernels: fused Adam, loss terms). Also read with ast by the pipeline's code hash, so
# a step that loads the extension reruns when one of them changes.
NATIVE_SOURCES = (
    "csrc/rasterize.cpp",
    "csrc/project.cpp",
    "../kernels/csrc/ssim.cpp",
    "../kernels/csrc/adam.cpp",
    "csrc/simd.h",
)
SOURCES = tuple(s for s in NATIVE_SOURCES if s.endswith(".cpp"))
HEADERS = tuple(s for s in NATIVE_SOURCES if s.endswith(".h"))
CFLAGS = ("-O3", "-march=native", "-fopenmp", "-fno-math-errno")
LDFLAGS = ("-fopenmp",)


class ExtensionBuildError(RuntimeError):
    """The compiled CPU rasterizer could not be built (no compiler, compile error)."""


@dataclass
class BuildTime:
    """Seconds this process spent compiling the extension (0 when it was only loaded). A one-time cost
    that whoever times a piece of work (e.g. the pipeline runner timing a step) can report apart."""

    seconds: float = 0.0


BUILD_TIME = BuildTime()


def _cpu_flags() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(("flags", "Features")):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def build_key() -> str:
    """Hash of everything that changes the binary."""
    import torch

    h = hashlib.sha256()
    # the checkout's path too: torch's ninja build files name the sources by absolute path, so two
    # checkouts sharing one build dir would rebuild it in turn (~100 s inside whichever step loads it first)
    h.update(str(CSRC).encode())
    for name in SOURCES + HEADERS:
        h.update(name.encode())
        h.update((HERE / name).read_bytes())
    h.update(" ".join(CFLAGS + LDFLAGS).encode())
    h.update(torch.__version__.encode())
    h.update(ninja_version().encode())
    h.update(sys.version.encode())
    h.update(_cpu_flags().encode())
    return h.hexdigest()[:16]


def build_root() -> Path:
    env = os.environ.get("TORCH_EXTENSIONS_DIR")
    return Path(env) if env else Path.home() / ".cache" / "go-pipeline" / "torch_extensions"


def check_compiler() -> str:
    """The C++ compiler torch will use (``$CXX`` or ``c++``); ExtensionBuildError if it is missing."""
    cxx = os.environ.get("CXX", "c++")
    if shutil.which(cxx) is None:
        raise ExtensionBuildError(
            f"the CPU rasterizer needs a C++ compiler ({cxx!r} not found on PATH); install g++ "
            "(e.g. `apt-get install g++`) or use backend='reference'"
        )
    return cxx


def ninja_version() -> str:
    """Version of the pinned PyPI ``ninja`` package (part of the build key)."""
    from importlib import metadata

    try:
        return metadata.version("ninja")
    except metadata.PackageNotFoundError:
        return "missing"


def find_ninja() -> Path:
    """The ``ninja`` executable installed by the PyPI ``ninja`` package (never another one on PATH)."""
    from importlib import metadata

    try:
        files = metadata.files("ninja") or []
    except metadata.PackageNotFoundError:
        files = []
    for f in files:
        if f.name == "ninja" and "bin" in f.parts:
            exe = Path(f.locate()).resolve()
            if exe.is_file() and os.access(exe, os.X_OK):
                return exe
    raise ExtensionBuildError(
        "the CPU rasterizer is built with the `ninja` of the PyPI package, which is not installed; "
        "install go-pipeline's dependencies (`pip install ninja`)"
    )


@contextlib.contextmanager
def _pinned_ninja() -> Iterator[None]:
    """PATH with the PyPI ninja first, for the duration of a build (torch runs ``ninja`` from PATH)."""
    old = os.environ.get("PATH", "")
    os.environ["PATH"] = str(find_ninja().parent) + os.pathsep + old
    try:
        yield
    finally:
        os.environ["PATH"] = old


@contextlib.contextmanager
def build_lock(build_dir: Path) -> Iterator[None]:
    """Exclusive ``go-build.lock`` for building in ``build_dir``; clears a stale torch ``lock`` file.

    Every builder holds this lock around torch's build, so whoever holds it and still finds torch's
    ``lock`` file knows its creator died mid-build (the kernel dropped that builder's lock): the file is
    removed with a message naming the dead pid, instead of torch waiting on it forever."""
    path = build_dir / "go-build.lock"
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode("ascii", "replace").strip() or "?"
            _notice(f"waiting for another process (pid {holder}) building the CPU rasterizer in {build_dir}")
            fcntl.flock(fd, fcntl.LOCK_EX)
        previous = os.pread(fd, 64, 0).decode("ascii", "replace").strip() or "an unknown process"
        torch_lock = build_dir / "lock"
        if torch_lock.exists():
            _notice(
                f"removing a stale build lock {torch_lock} left by pid {previous}, which is no longer "
                "running (killed during the build?)"
            )
            torch_lock.unlink(missing_ok=True)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
        yield
    finally:
        os.close(fd)  # releases the flock


def _notice(message: str) -> None:
    """One line for the user: through logging when the caller set it up (the step worker does), else
    on stderr."""
    if log.hasHandlers() and log.getEffectiveLevel() <= logging.INFO:
        log.info(message)
    else:
        print(message, file=sys.stderr, flush=True)


def _needs_build(build_dir: Path, name: str) -> bool:
    """True when loading will compile: no library yet, or ninja (dry run) finds work to do."""
    import subprocess

    if not any(build_dir.glob(f"{name}*.so")):
        return True
    if not (build_dir / "build.ninja").is_file():
        return True
    try:
        out = subprocess.run(
            [str(find_ninja()), "-n", "-C", str(build_dir)], capture_output=True, text=True, timeout=60
        )
    except (OSError, subprocess.SubprocessError):
        return True
    return out.returncode != 0 or "no work to do" not in out.stdout


def _library_stamp(build_dir: Path, name: str) -> tuple[int, ...]:
    return tuple(sorted(p.stat().st_mtime_ns for p in build_dir.glob(f"{name}*.so")))


@functools.cache
def load_extension(verbose: bool = False):
    """The compiled module (built on first use; cached on disk and in this process)."""
    from torch.utils import cpp_extension

    check_compiler()
    name = f"go_raster_cpu_{build_key()}"
    build_dir = build_root() / name
    build_dir.mkdir(parents=True, exist_ok=True)
    with build_lock(build_dir), _pinned_ninja():
        if _needs_build(build_dir, name):
            _notice(
                f"compiling the CPU rasterizer once for this machine and source version (1-3 min; "
                f"cached in {build_dir}; not counted in any step's time) ..."
            )
        before = _library_stamp(build_dir, name)
        t0 = time.perf_counter()
        try:
            module = cpp_extension.load(
                name=name,
                sources=[str((HERE / s).resolve()) for s in SOURCES],
                extra_include_paths=[str(CSRC)],  # simd.h for the kernels in go_core/kernels
                extra_cflags=list(CFLAGS),
                extra_ldflags=list(LDFLAGS),
                build_directory=str(build_dir),
                verbose=verbose,
            )
        except Exception as exc:  # compile/link errors come as RuntimeError/CalledProcessError
            raise ExtensionBuildError(f"building the CPU rasterizer in {build_dir} failed: {exc}") from exc
        if _library_stamp(build_dir, name) != before:  # (re)built: compiled and linked now
            BUILD_TIME.seconds += time.perf_counter() - t0
    return module


def main() -> int:
    import time

    t0 = time.perf_counter()
    try:
        load_extension(verbose="-v" in sys.argv[1:])
    except ExtensionBuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"CPU rasterizer ready in {build_root()} ({time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
