"""SSIM loss benchmark: the torch path (``ssim_map(...).mean()``) vs the compiled kernel (``losses.ssim``).

    python benchmarks/archive/ssim_loss.py [--json benchmarks/results/archive/ssim_loss_cpu.json] \
                                   [--sizes 256,512] [--repeats 30] [--threads N]

Both run in this process on the same float32 [H,W,3] pair, called as the coarse loop's ``view_loss`` calls
them (``rgb.permute(2, 0, 1)[None]``), their repeats interleaved so both see the same machine load.
``fwd_ms``: forward with a gradient wanted (the kernel also stores its backward partials);
``fwdbwd_ms``: forward + backward. Medians of wall time after 3 warm-ups; ``*_cpu_ms``: the same in CPU
time of all threads (``time.process_time``), the better number when other processes share the cores.
``err_vs_f64``: |value - float64 reference|, showing the kernel's double-precision filtering.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

from _machine import cpu_name  # benchmarks/ is on sys.path when run as a script

DEFAULT_JSON = Path(__file__).resolve().parents[1] / "results" / "archive" / "ssim_loss_cpu.json"


def _pair(size: int):
    import torch

    g = torch.Generator().manual_seed(size)
    gt = torch.rand(size, size, 3, generator=g)
    rgb = (gt + 0.1 * torch.randn(size, size, 3, generator=g)).clamp(0, 1)
    return rgb.requires_grad_(True), gt


def measure(size: int, repeats: int) -> list[dict]:
    """Records for the torch path and the kernel at one image size."""
    import torch

    from go_core.coarse.losses import ssim, ssim_map
    from go_core.render.build import load_extension

    load_extension()
    rgb, gt = _pair(size)
    paths = {
        "torch": lambda: ssim_map(rgb.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None]).mean(),
        "kernel": lambda: ssim(rgb.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None]),
    }
    with torch.no_grad():
        ref = ssim_map(rgb.double(), gt.double()).mean().item()
    times = {name: {"fwd": [], "fwdbwd": [], "fwd_cpu": [], "fwdbwd_cpu": []} for name in paths}
    for it in range(repeats + 3):
        for name, fn in paths.items():
            rgb.grad = None
            c0, t0 = time.process_time(), time.perf_counter()
            value = fn()
            c1, t1 = time.process_time(), time.perf_counter()
            value.backward()
            c2, t2 = time.process_time(), time.perf_counter()
            if it >= 3:
                rec = times[name]
                rec["fwd"].append(t1 - t0)
                rec["fwdbwd"].append(t2 - t0)
                rec["fwd_cpu"].append(c1 - c0)
                rec["fwdbwd_cpu"].append(c2 - c0)
    records = []
    for name, fn in paths.items():
        with torch.no_grad():
            err = abs(fn().item() - ref)
        rec = {"size": size, "path": name}
        rec.update({f"{k}_ms": round(1e3 * statistics.median(v), 3) for k, v in times[name].items()})
        rec.update({"err_vs_f64": float(f"{err:.3g}"), "threads": torch.get_num_threads()})
        records.append(rec)
    return records


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", type=Path, default=DEFAULT_JSON, help="write the records here")
    ap.add_argument("--sizes", default="256,512", help="square image sizes, comma-separated")
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    args = ap.parse_args(argv)

    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
    records = []
    for size in (int(s) for s in args.sizes.split(",")):
        for r in measure(size, args.repeats):
            records.append(r)
            print(
                f"{size:4d}² {r['path']:6s}  fwd {r['fwd_ms']:7.2f} ms  fwd+bwd {r['fwdbwd_ms']:7.2f} ms"
                f"  (cpu {r['fwd_cpu_ms']:7.2f} / {r['fwdbwd_cpu_ms']:7.2f})  |err| {r['err_vs_f64']:.1e}",
                flush=True,
            )
        t, k = records[-2], records[-1]
        print(
            f"{size:4d}² speed-up  fwd {t['fwd_ms'] / k['fwd_ms']:.1f}x  fwd+bwd "
            f"{t['fwdbwd_ms'] / k['fwdbwd_ms']:.1f}x",
            flush=True,
        )
    out = {
        "machine": {
            "cpu": cpu_name(),
            "cores": os.cpu_count(),
            "loadavg_1min": round(os.getloadavg()[0], 2),
            "torch": torch.__version__,
        },
        "repeats": args.repeats,
        "records": records,
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
