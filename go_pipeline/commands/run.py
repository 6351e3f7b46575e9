"""``go-pipeline run SCENE``: run the stale steps; ``go-pipeline run --example``: the built-in example."""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from go_pipeline.commands._common import add_pipeline_args, overrides_from

EXAMPLE_PROFILE = "example"
EXAMPLE_DIR = "go-example"


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "run",
        help="run the pipeline's stale steps on a scene",
        description="Run every stale step of the pipeline on SCENE, in topological order, "
        "reusing cached artifacts (see `go-pipeline status`).",
    )
    p.add_argument("scene", nargs="?", help="scene folder (NeRF-synthetic transforms_*.json or COLMAP)")
    p.add_argument(
        "--example",
        action="store_true",
        help=f"copy the built-in example scene to --workdir (default ./{EXAMPLE_DIR}) and run it "
        f"with profile '{EXAMPLE_PROFILE}'",
    )
    add_pipeline_args(p)
    p.add_argument("--until", metavar="STEP", help="stop after STEP (runs only STEP and its ancestors)")
    p.add_argument("--force", action="append", default=[], metavar="STEP", help="rerun STEP even if cached")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto", help="compute device")
    p.add_argument(
        "--in-process",
        action="store_true",
        help="run steps in this process (for debuggers) instead of one child process per step",
    )
    p.add_argument("--quiet", action="store_true", help="print only errors")
    p.set_defaults(func=main)


def _example_scene(args: argparse.Namespace) -> tuple[Path, str | None]:
    """Copy the packaged example scene into the work folder (once) and return it; artifacts go to its .go/."""
    from go_core.errors import GoError
    from go_pipeline.resources import example_scene_path

    if args.scene:
        raise GoError("give either SCENE or --example, not both", args.scene)
    source = example_scene_path()
    if not (source / "transforms_train.json").is_file():
        raise GoError("the packaged example scene is missing (broken install?)", source)
    base = Path(args.workdir or EXAMPLE_DIR).resolve()
    scene = base / source.name
    if not scene.is_dir():
        base.mkdir(parents=True, exist_ok=True)
        tmp = base / f".{source.name}.copying"
        shutil.rmtree(tmp, ignore_errors=True)
        shutil.copytree(source, tmp)
        for p in tmp.rglob("*"):  # the installed copy may be read-only
            p.chmod(p.stat().st_mode | 0o200)
        tmp.rename(scene)
    return scene, None


def main(args: argparse.Namespace) -> int:
    from go_core.errors import GoError
    from go_pipeline.runner import run_pipeline

    workdir = args.workdir
    profile = args.profile
    if args.example:
        scene, workdir = _example_scene(args)
        profile = profile or EXAMPLE_PROFILE
        print(f"example scene: {scene} (artifacts in {scene / '.go'})", file=sys.stderr)
    elif not args.scene:
        raise GoError("missing SCENE (a scene folder), or use --example")
    else:
        scene = Path(args.scene)
    summary = run_pipeline(
        scene,
        workdir=workdir,
        profile=profile,
        overrides=overrides_from(args),
        until=args.until,
        force=args.force,
        seed=args.seed,
        pipeline_path=args.pipeline,
        device=args.device,
        in_process=args.in_process,
        quiet=args.quiet,
        debug=args.debug,
    )
    if not args.quiet and summary.log_path is not None:
        print(f"log: {summary.log_path}", file=sys.stderr)
    return 0
