"""Rasterizer benchmark: forward and forward+backward time, peak memory, Gaussian-pixel evaluations/s.

    python benchmarks/rasterizer.py [--json OUT.json] [--cases 10k_256,50k_256] [--backends cpu,reference]
                                    [--repeats 5] [--ref-cases 10k_256,50k_256]

Cases (N Gaussians, image size): 10k_256, 50k_256, 50k_512, 200k_512, each a synthetic object
(go_core.render.synthetic.benchmark_scene: screen-space sigma 1-8 px, SH degree 3, one camera).
Every (case, backend) runs in a fresh subprocess.

* ``fwd_ms``: forward pass with gradients enabled (as in training); ``fwdbwd_ms``: forward + backward of
  a loss on rgb, alpha and depth. Medians over ``--repeats`` runs after one warm-up (reference:
  ``--ref-repeats`` runs, no warm-up). ``*_cpu_ms``: the same in CPU time of all threads, meaningful
  when other processes share the cores.
* ``peak_mb``: peak resident memory above the footprint just before the first render (Linux's
  resettable VmHWM; GPU: torch.cuda.max_memory_allocated).
* ``evals_per_s``: tile-Gaussian pairs of the 3-sigma rectangles (``pairs``) x 256 pixels / forward
  seconds. ``pairs_binned`` (CPU backend): the pairs its binning keeps (tiles a Gaussian can reach).

The reference backend runs only on ``--ref-cases`` and where its estimated time (from the first case)
stays under ``--ref-budget-s``; its memory is bounded (checkpointed chunks), it is only slow.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

CASES = {
    "10k_256": (10_000, 256),
    "50k_256": (50_000, 256),
    "50k_512": (50_000, 512),
    "200k_512": (200_000, 512),
}


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _reset_peak_rss() -> None:
    """Reset the kernel's resident-set high-water mark (VmHWM) of this process (Linux >= 4.0)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass


def _peak_rss_mb() -> float:
    """VmHWM of this process since the last reset; falls back to ru_maxrss."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def measure(case: str, backend: str, repeats: int) -> dict:
    """Run one (case, backend) in this process and return its record."""
    import torch

    from go_core.render import render
    from go_core.render.projection import project_gaussians
    from go_core.render.synthetic import benchmark_scene
    from go_core.render.tiles import bin_gaussians

    n, size = CASES[case]
    device = "cuda" if backend == "cuda" else "cpu"
    scene = [t.to(device) for t in benchmark_scene(n, size)]
    params = [t.clone().requires_grad_() for t in scene[:5]]
    if backend == "cpu":
        from go_core.render.build import load_extension

        load_extension()

    def sync():
        if device == "cuda":
            torch.cuda.synchronize()

    def forward():
        return render(*params, scene[5], scene[6], size, size, sh_degree=3, backend=backend)

    def loss(out):
        return out.rgb.square().sum() + out.alpha.sum() + 0.1 * out.depth.sum()

    _reset_peak_rss()
    base = _rss_mb()
    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()
    fwd, fwdbwd, cpu_fwd, cpu_fwdbwd = [], [], [], []
    warm = 0 if backend == "reference" else 1  # pure torch needs no warm-up; its runs are long
    for it in range(repeats + warm):
        for p in params:
            p.grad = None
        sync()
        c0, t0 = time.process_time(), time.perf_counter()
        out = forward()
        sync()
        c1, t1 = time.process_time(), time.perf_counter()
        loss(out).backward()
        sync()
        c2, t2 = time.process_time(), time.perf_counter()
        del out
        if it >= warm:
            fwd.append(t1 - t0)
            fwdbwd.append(t2 - t0)
            cpu_fwd.append(c1 - c0)
            cpu_fwdbwd.append(c2 - c0)
    if device == "cuda":
        peak = torch.cuda.max_memory_allocated() / 2**20
    else:
        peak = _peak_rss_mb() - base
    with torch.no_grad():  # tile-Gaussian pairs per forward: 3-sigma rectangles (reference binning)
        proj = project_gaussians(*[t.cpu() for t in scene], size, size, sh_degree=3)
        pairs = int(
            bin_gaussians(proj.means2d[0], proj.depths[0], proj.radii[0], size, size).gauss_ids.numel()
        )
        extra = {}
        if backend == "cpu":  # the compiled binning drops the rectangle tiles a Gaussian cannot reach
            from go_core.render.build import load_extension

            inputs = [
                t.float().contiguous()
                for t in (proj.means2d, proj.conics, proj.colors, proj.depths, proj.opacities, proj.depths)
            ]
            binned = load_extension().bin_and_pack(*inputs, proj.radii.int(), size, size)
            extra["pairs_binned"] = int(binned[2].numel())
    f = statistics.median(fwd)
    return {
        "case": case,
        "backend": backend,
        "fwd_ms": round(1e3 * f, 2),
        "fwdbwd_ms": round(1e3 * statistics.median(fwdbwd), 2),
        "peak_mb": round(peak, 1),
        "evals_per_s": float(f"{pairs * 256 / f:.4g}"),
        "pairs": pairs,
        **extra,
        # CPU seconds of all threads (robust to other processes sharing the cores; wall ≥ this / threads)
        "fwd_cpu_ms": round(1e3 * statistics.median(cpu_fwd), 2),
        "fwdbwd_cpu_ms": round(1e3 * statistics.median(cpu_fwdbwd), 2),
        "threads": torch.get_num_threads(),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", type=Path, help="write the records to this JSON file")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--backends", default=None, help="default: cpu,reference (+cuda when available)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--ref-repeats", type=int, default=1)
    ap.add_argument("--ref-budget-s", type=float, default=300.0)
    ap.add_argument("--ref-cases", default="10k_256,50k_256", help="cases the reference runs on ('all')")
    ap.add_argument("--worker", nargs=2, metavar=("CASE", "BACKEND"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if args.worker:
        case, backend = args.worker
        reps = args.ref_repeats if backend == "reference" else args.repeats
        print(json.dumps(measure(case, backend, reps)))
        return 0

    if args.backends:
        backends = args.backends.split(",")
    else:
        import torch

        backends = ["cpu", "reference"] + (["cuda"] if torch.cuda.is_available() else [])
    records, ref_rate = [], None
    for case in args.cases.split(","):
        if case not in CASES:
            ap.error(f"unknown case {case!r}; choose from {', '.join(CASES)}")
        for backend in backends:
            if backend == "reference" and args.ref_cases != "all" and case not in args.ref_cases.split(","):
                print(f"{case:9s} reference  skipped (not in --ref-cases)", flush=True)
                continue
            if backend == "reference" and ref_rate is not None:
                est = CASES[case][0] * ref_rate * (args.ref_repeats + 1)  # repeats + probe
                if est > args.ref_budget_s:
                    print(
                        f"{case:9s} reference  skipped (estimated {est:.0f} s > --ref-budget-s)", flush=True
                    )
                    continue
            cmd = [
                sys.executable,
                __file__,
                "--worker",
                case,
                backend,
                "--repeats",
                str(args.repeats),
                "--ref-repeats",
                str(args.ref_repeats),
            ]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                print(f"{case:9s} {backend:10s} FAILED: {proc.stderr.strip().splitlines()[-1:]}", flush=True)
                continue
            rec = json.loads(proc.stdout.strip().splitlines()[-1])
            records.append(rec)
            if backend == "reference":
                ref_rate = rec["fwdbwd_ms"] / 1e3 / CASES[case][0]
            print(
                f"{case:9s} {backend:10s} fwd {rec['fwd_ms']:9.1f} ms  fwd+bwd {rec['fwdbwd_ms']:9.1f} ms  "
                f"peak {rec['peak_mb']:7.0f} MB  {rec['evals_per_s']:.3g} evals/s  ({rec['pairs']} pairs"
                f"{', ' + str(rec['pairs_binned']) + ' binned' if 'pairs_binned' in rec else ''}, "
                f"{rec['threads']} threads)",
                flush=True,
            )
    by = {(r["case"], r["backend"]): r for r in records}
    for case in args.cases.split(","):
        if (case, "cpu") in by and (case, "reference") in by:
            ratio = by[(case, "reference")]["fwdbwd_ms"] / by[(case, "cpu")]["fwdbwd_ms"]
            print(f"{case}: cpu is {ratio:.1f}x faster than the reference (fwd+bwd)")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(records, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
