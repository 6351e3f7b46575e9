"""``go-pipeline status SCENE``: every step as fresh / stale / missing, and why (like ``dvc status``)."""

from __future__ import annotations

import argparse
import json
import sys

from go_pipeline.commands._common import add_pipeline_args, settings_from


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("status", help="show which steps are fresh, stale or missing, and why")
    p.add_argument("scene", help="scene folder")
    add_pipeline_args(p)
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument(
        "--verify",
        action="store_true",
        help="hash every artifact file and compare with its manifest (default: sizes only)",
    )
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from go_pipeline import store
    from go_pipeline.lock import WorkdirLock
    from go_pipeline.runner import pipeline_status

    workdir = store.workdir_for(args.scene, args.workdir)
    saved, settings = settings_from(args, workdir)  # the work dir's remembered profile / --set / seed
    rows = pipeline_status(
        args.scene,
        workdir=args.workdir,
        profile=settings.profile,
        overrides=settings.sets,
        seed=settings.seed,
        pipeline_path=args.pipeline,
        allow_custom_steps=args.allow_custom_steps,
        verify=args.verify,
        allow_outside=args.allow_outside,
    )
    running = WorkdirLock(workdir).holder_info()
    if args.json:
        print(json.dumps([row.__dict__ for row in rows], indent=2))
        return 0
    if saved is not None or settings.profile or settings.sets:
        sets = ", ".join(f"{k}={v}" for k, v in settings.sets.items()) or "none"
        where = f" ({workdir / 'params.yaml'} and the flags given)" if saved is not None else ""
        print(
            f"settings{where}: profile {settings.profile or '(none)'}, seed {settings.seed}, --set {sets}",
            file=sys.stderr,
        )
    width = max(len(r.step) for r in rows)
    for r in rows:
        why = f"  ({r.reason})" if r.reason else ""
        print(f"{r.step:<{width}}  {r.state:<7}{why}")
    if running is not None:
        print(f"(a `go-pipeline {running[1]}`, pid {running[0]}, is working on this scene now)")
    stale = sum(r.state != "fresh" for r in rows)
    print(f"{len(rows) - stale} fresh, {stale} to run" if stale else "everything is up to date")
    return 0
