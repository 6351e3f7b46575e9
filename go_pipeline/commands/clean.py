"""``go-pipeline clean SCENE``: delete the work dir, or only some steps' artifacts and checkpoints."""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("clean", help="delete cached artifacts (all, --step STEP, or --old)")
    p.add_argument("scene", help="scene folder")
    p.add_argument("--workdir", metavar="W", help="the work dir (default: SCENE/.go)")
    p.add_argument(
        "--step",
        action="append",
        default=[],
        metavar="STEP",
        help="delete only this step's artifacts and checkpoints (repeatable)",
    )
    p.add_argument(
        "--old",
        action="store_true",
        help="keep each step's current artifact, delete the others and stale checkpoints",
    )
    p.set_defaults(func=main)


def clean(workdir: Path, steps: list[str] | None = None, old: bool = False) -> list[Path]:
    """Delete (under the work dir's lock) and return what was deleted."""
    from go_pipeline import store
    from go_pipeline.lock import WorkdirLock

    removed: list[Path] = []
    if not workdir.is_dir():
        return removed
    with WorkdirLock(workdir):
        if not steps and not old:
            for child in sorted(workdir.iterdir()):
                if child.name == "lock":
                    continue
                if child.is_dir():
                    shutil.rmtree(child)
                else:
                    child.unlink()
                removed.append(child)
            return removed
        names = steps or sorted(p.name for p in (workdir / "artifacts").glob("*") if p.is_dir())
        for step in names:
            keep = store.read_ref(workdir, step) if old else None
            for root in (store.artifacts_root(workdir, step), workdir / "checkpoints" / step):
                if not root.is_dir():
                    continue
                for p in sorted(root.iterdir()):
                    if keep is not None and p.name == keep:
                        continue
                    store.remove_tree(p) if p.is_dir() else p.unlink()
                    removed.append(p)
            if not old:
                store.ref_path(workdir, step).unlink(missing_ok=True)
    return removed


def main(args: argparse.Namespace) -> int:
    from go_core.errors import GoError
    from go_pipeline import store

    scene = Path(args.scene)
    if not scene.is_dir():
        raise GoError("scene folder not found", scene)
    workdir = store.workdir_for(scene, args.workdir)
    if args.step:
        from go_pipeline.pipeline import load_pipeline

        known = set(load_pipeline().steps) | {p.name for p in (workdir / "artifacts").glob("*")}
        for s in args.step:
            if s not in known:
                raise GoError(f"--step {s}: unknown step (steps: {', '.join(sorted(known))})")
    removed = clean(workdir, args.step or None, args.old)
    print(f"removed {len(removed)} item(s) from {workdir}", file=sys.stderr)
    return 0
