"""``go-pipeline run SCENE``: run the stale steps; ``go-pipeline run --example``: the built-in example."""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from go_pipeline.commands._common import add_pipeline_args

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
    p.add_argument(
        "--output",
        metavar="DIR",
        help="put the results (model.ply, turntable, metrics.json, report.html) here "
        "(default: WORKDIR/outputs)",
    )
    p.add_argument("--quiet", action="store_true", help="print only errors")
    p.add_argument(
        "--verify",
        action="store_true",
        help="check every cached artifact's files against their content hashes (always: their sizes, "
        "and the hashes of the artifacts a running step reads); a damaged one is recomputed",
    )
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
    from go_pipeline import store
    from go_pipeline.commands._common import settings_from
    from go_pipeline.pipeline import load_pipeline
    from go_pipeline.runner import run_pipeline
    from go_pipeline.workspace import describe_changes, save_settings

    workdir = args.workdir
    default_profile = None
    if args.example:
        scene, workdir = _example_scene(args)
        default_profile = EXAMPLE_PROFILE
        scene_arg = _shown(scene)
        if not args.quiet:
            print(f"example scene: {scene_arg} (artifacts in {_shown(scene / '.go')})", file=sys.stderr)
    elif not args.scene:
        raise GoError("missing SCENE (a scene folder), or use --example")
    else:
        scene = Path(args.scene)
        scene_arg = args.scene
    wd = store.workdir_for(scene, workdir)
    saved, settings = settings_from(args, wd, default_profile)
    pipeline = load_pipeline(args.pipeline)
    changes = describe_changes(pipeline, saved, settings)  # also checks --set / --profile
    if changes and not args.quiet:
        print(f"settings changed since the last run ({_shown(wd / 'params.yaml')}):", file=sys.stderr)
        for line in changes:
            print(f"  {line}", file=sys.stderr)
    summary = run_pipeline(
        scene,
        workdir=workdir,
        profile=settings.profile,
        overrides=settings.sets,
        until=args.until,
        force=args.force,
        seed=settings.seed,
        pipeline_path=args.pipeline,
        allow_custom_steps=args.allow_custom_steps,
        verify=args.verify,
        allow_outside=args.allow_outside,
        device=args.device,
        in_process=args.in_process,
        quiet=args.quiet,
        debug=args.debug,
        on_start=lambda w: save_settings(w, pipeline, settings),
    )
    if args.until is not None:  # a partial run: the outputs keep showing the last complete one
        if not args.quiet:
            print(f"stopped after {args.until}; results not published (run without --until)", file=sys.stderr)
        return 0
    from go_pipeline.outputs import publish, result_lines

    files = publish(
        summary.scene_dir,
        summary.workdir,
        {s.name: s.key for s in summary.steps},
        args.output,
        args.pipeline,
    )
    if not args.quiet:
        if summary.log_path is not None:
            print(f"log: {_shown(summary.log_path)}", file=sys.stderr)
        for line in result_lines(summary, files, scene_arg, settings.profile):
            print(line)
    return 0


def _shown(path: Path) -> str:
    """``path`` relative to the current folder when it lies below it (shorter, and what the user typed)."""
    try:
        return str(Path(path).resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(path)
