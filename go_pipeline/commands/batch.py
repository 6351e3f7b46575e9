"""`go-pipeline batch ROOT`: run every scene folder under ROOT on Ray (cache-aware), one task per scene;
a failing scene is reported and the others continue; results as CSV + JSON + a Markdown table."""

from __future__ import annotations

import argparse
from pathlib import Path

from go_pipeline.commands._common import add_pipeline_args, overrides_from


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("batch", help="run every scene of a dataset folder on Ray and tabulate results")
    p.add_argument("root", type=Path, help="folder whose sub-folders are scenes")
    p.add_argument("--out", type=Path, default=None, help="where the results go (default: ROOT)")
    p.add_argument(
        "--workdir-root",
        type=Path,
        default=None,
        help="per-scene work dirs W/<scene> (default: each SCENE/.go)",
    )
    p.add_argument("--until", metavar="STEP", help="stop after this step")
    p.add_argument("--device", choices=["auto", "cpu", "cuda"], default="auto")
    p.add_argument("--ray-address", default=None, help="join a Ray cluster (default: start Ray locally)")
    p.add_argument("--num-cpus", type=int, default=None, help="local Ray CPUs (default: all of the machine)")
    p.add_argument("--cpus-per-scene", type=float, default=1.0, help="Ray CPUs reserved per scene task")
    p.add_argument("--gpus-per-scene", type=float, default=0.0, help="Ray GPUs reserved per scene task")
    p.add_argument(
        "--retries",
        type=int,
        default=2,
        help="rerun a scene whose Ray worker or node died, up to this many times (it resumes from its "
        "work dir; default 2)",
    )
    add_pipeline_args(p)
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from go_core.extras import require_extra
    from go_pipeline.reporting.batch import find_scenes, run_batch, write_results

    require_extra("ray", "go-pipeline batch (scenes on Ray)")  # one line, before anything else
    scenes = find_scenes(args.root)
    print(f"{len(scenes)} scenes under {args.root}: " + ", ".join(s.name for s in scenes))
    options = {
        "workdir_root": str(args.workdir_root.resolve()) if args.workdir_root else None,
        "profile": args.profile,
        "overrides": overrides_from(args),
        "until": args.until,
        "seed": args.seed or 0,
        "pipeline_path": str(Path(args.pipeline).resolve()) if args.pipeline else None,
        "device": args.device,
        "allow_custom_steps": args.allow_custom_steps,
        "allow_outside": args.allow_outside,
    }
    result = run_batch(
        args.root,
        ray_address=args.ray_address,
        retries=args.retries,
        num_cpus=args.num_cpus,
        cpus_per_scene=args.cpus_per_scene,
        gpus_per_scene=args.gpus_per_scene,
        options=options,
        scenes=scenes,
    )
    paths = write_results(result, args.out or args.root)
    print(paths["md"].read_text(), end="")
    print(f"results: {paths['csv']}, {paths['json']}")
    for r in result.rows:
        if r["status"] != "ok":
            print(f"FAILED {r['scene']}: {r['error']}")
    return 1 if result.failed else 0
