"""Size and inference time of the repair prior (go_core.compact.prior) at 256x256: the issue-34 limits are
weights <= 30 MB and <= 0.2 s per view on 2 cores. Random weights (the time does not depend on them)::

    python benchmarks/archive/repair_prior_speed.py \\
        --out benchmarks/results/repair_prior_speed.json

Reports per configuration: parameters, float32 MB, median seconds per 256x256 view over ``--repeat`` runs
(after one warm-up), and the torch thread count it ran with.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import asdict
from pathlib import Path

import torch

from go_core.compact.prior import PriorConfig, RepairPrior


def time_config(config: PriorConfig, size: int, repeat: int) -> dict:
    model = RepairPrior(config).eval()
    x = torch.rand(1, config.in_channels, size, size)
    params = sum(p.numel() for p in model.parameters())
    times = []
    with torch.no_grad():
        model(x)
        for _ in range(repeat):
            t0 = time.perf_counter()
            model(x)
            times.append(time.perf_counter() - t0)
    times.sort()
    return {
        "config": asdict(config),
        "params": params,
        "mb_float32": round(params * 4 / 2**20, 2),
        "s_per_view_median": round(times[len(times) // 2], 4),
        "s_per_view_min": round(times[0], 4),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--widths", type=int, nargs="+", default=[16, 24, 32, 48])
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    rows = [
        time_config(PriorConfig(width=w, levels=3, reference=ref), args.size, args.repeat)
        for w in args.widths
        for ref in (False, True)
    ]
    result = {
        "command": "python benchmarks/archive/repair_prior_speed.py " + " ".join(os.sys.argv[1:]),
        "torch_threads": torch.get_num_threads(),
        "cpu": os.uname().machine,
        "load_average": os.getloadavg(),
        "rows": rows,
    }
    print(json.dumps(result, indent=1))
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
