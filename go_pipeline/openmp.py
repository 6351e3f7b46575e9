"""How long idle OpenMP threads spin before they sleep; libgomp reads it once, so set it before torch loads.

A training iteration opens ~80 parallel regions (the compiled kernels, and every torch op on more than 32k
elements). Threads that sleep at once (``OMP_WAIT_POLICY=PASSIVE``) must be woken for each region, which on
a VM costs more than a small op's work (coarse iteration, 2 threads: ~20% slower than a short spin).
libgomp's default spin (~3 ms) and ``ACTIVE`` burn the time slices that other processes need: 2–7x slower
beside a busy process. A spin of ~10 µs (``GOMP_SPINCOUNT=1000``) bridges the gaps between the regions of
an iteration and costs nothing measurable beside busy processes (benchmarks/archive/omp_wait.py,
docs/rendering.md).
"""

from __future__ import annotations

from collections.abc import MutableMapping

SPIN_COUNT = "1000"
VARIABLES = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")


def set_default_wait(env: MutableMapping[str, str]) -> None:
    """Give ``env`` the short spin, unless the user chose a wait policy or a spin count themselves."""
    if not any(name in env for name in VARIABLES):
        env["GOMP_SPINCOUNT"] = SPIN_COUNT
