"""Build once per machine and load the compiled CPU rasterizer (`python -m go_core.render.build` prebuilds).

The extension (the rasterizer from go_core/render/csrc, and the kernels that are not rendering from
go_core/kernels/csrc: the fused Adam step and the loss terms ``go_core.losses`` reaches through
``torch.ops.go_ssim``) is compiled with the system C++ compiler through ``torch.utils.cpp_extension.load``
(ninja). The build directory is keyed by a hash of the sources and their
folder, flags, torch/python versions and the CPU's instruction-set flags (the code is built with
``-march=native``), under ``$TORCH_EXTENSIONS_DIR`` if set, else ``~/.cache/go-pipeline/torch_extensions``.
Later calls only load it.
"""

from __future__ import annotations

import functools
import hashlib
import os
import platform
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

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


@functools.cache
def load_extension(verbose: bool = False):
    """The compiled module (built on first use; cached on disk and in this process)."""
    from torch.utils import cpp_extension

    check_compiler()
    name = f"go_raster_cpu_{build_key()}"
    build_dir = build_root() / name
    build_dir.mkdir(parents=True, exist_ok=True)
    built_before = any(build_dir.glob(f"{name}*.so"))
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
    if not built_before:
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
