"""Full fine-tune vs LoRA (peft) for the compact repair model, on the built-in example (example profile).

Each variant changes the `tune` step's settings only (the coarse model, leave-one-out and noise pairs are
shared through the cache), then runs repair and eval; rows give test PSNR / SSIM / LPIPS*, the `tune` step's
CPU seconds and the restorer's L1 on the leave-one-out pairs after tuning. Plus the "no repair" and
"pretrained only" rows for reference.

    python benchmarks/archive/compact_method_example.py --workroot /tmp/lora_cmp \
        --out benchmarks/results/compact_method_example.json
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from pathlib import Path

VARIANTS = {
    "full (default)": {},
    "lora r4": {"tune.compact_method": "lora", "tune.compact_rank": 4},
    "lora r16": {"tune.compact_method": "lora", "tune.compact_rank": 16},
    "lora r16 lr 1e-3": {"tune.compact_method": "lora", "tune.compact_rank": 16, "tune.compact_lr": 1e-3},
    "no repair": {"repair.mode": "no_repair"},
    "pretrained only": {"tune.finetune": False},
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workroot", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()

    from go_pipeline.resources import example_scene_path
    from go_pipeline.runner import run_pipeline

    scene = args.workroot / "basket"
    if not scene.exists():
        shutil.copytree(example_scene_path(), scene)
    rows = {}
    for tag, sets in VARIANTS.items():
        t0 = time.perf_counter()
        summary = run_pipeline(
            scene, workdir=args.workroot / "work", profile="example", overrides=sets, quiet=True
        )
        mean = json.loads((summary.step("eval").artifact_dir / "metrics.json").read_text())["mean"]
        lora = json.loads((summary.step("tune").artifact_dir / "manifest.json").read_text())
        rows[tag] = {
            **{k: mean[k] for k in ("psnr", "ssim", "lpips_star")},
            "lora_cpu_s": lora.get("cpu_s"),
            "loo_pairs_l1_after": summary.step("tune").record.get("loo_pairs_l1_after"),
            "run_wall_s": round(time.perf_counter() - t0, 1),
        }
        print(tag, rows[tag], flush=True)
    result = {
        "command": "python benchmarks/archive/compact_method_example.py " + " ".join(os.sys.argv[1:]),
        "cpu_count": os.cpu_count(),
        "rows": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
