"""``go-pipeline clean SCENE``: delete the work dir, or only some steps' artifacts and checkpoints.

``--dry-run`` lists what would go (with sizes); on a terminal it asks before deleting (``-y`` does not ask).
"""

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
        help="keep each step's current artifact, delete the others and stale checkpoints (= `gc`)",
    )
    add_confirm_args(p)
    p.set_defaults(func=main)


def add_confirm_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("-n", "--dry-run", action="store_true", help="list what would be deleted; delete nothing")
    p.add_argument("-y", "--yes", action="store_true", help="do not ask for confirmation on a terminal")


def plan_clean(workdir: Path, steps: list[str] | None = None, old: bool = False) -> list[Path]:
    """What ``clean`` deletes: everything in the work dir (not its lock), or only ``steps``' artifacts and
    checkpoints; with ``old``, all but each step's current artifact (the latest run's, refs/)."""
    from go_pipeline import store

    if not workdir.is_dir():
        return []
    if not steps and not old:
        return [c for c in sorted(workdir.iterdir()) if c.name != "lock"]
    found: list[Path] = []
    names = steps or sorted(p.name for p in (workdir / "artifacts").glob("*") if p.is_dir())
    for step in names:
        keep = store.read_ref(workdir, step) if old else None
        for root in (store.artifacts_root(workdir, step), workdir / "checkpoints" / step):
            if root.is_dir():
                found += [p for p in sorted(root.iterdir()) if keep is None or p.name != keep]
        if not old and store.ref_path(workdir, step).exists():
            found.append(store.ref_path(workdir, step))
    return found


def size_of(path: Path) -> int:
    if path.is_file() or path.is_symlink():
        return path.lstat().st_size
    return sum(p.lstat().st_size for p in path.rglob("*") if p.is_file())


def clean(workdir: Path, steps: list[str] | None = None, old: bool = False) -> list[Path]:
    """Delete (under the work dir's lock) and return what was deleted."""
    from go_pipeline import store
    from go_pipeline.lock import WorkdirLock

    if not workdir.is_dir():
        return []
    with WorkdirLock(workdir, command="clean"):
        removed = plan_clean(workdir, steps, old)
        for p in removed:
            if p.is_dir() and not p.is_symlink():
                (
                    store.remove_tree
                    if p.parent.parent.name in ("artifacts", "checkpoints")
                    else shutil.rmtree
                )(p)
            else:
                p.unlink(missing_ok=True)
    return removed


def confirm_and_clean(workdir: Path, steps: list[str] | None, old: bool, args: argparse.Namespace) -> int:
    """List (``--dry-run``), ask on a terminal unless ``--yes``, then delete; the shared body of clean/gc."""
    items = plan_clean(workdir, steps, old)
    total = sum(size_of(p) for p in items)
    what = f"{len(items)} item(s), {total / 1e6:.1f} MB, from {workdir}"
    if args.dry_run:
        for p in items:
            print(f"would delete {p.relative_to(workdir)}  ({size_of(p) / 1e6:.1f} MB)")
        print(f"dry run: would delete {what}")
        return 0
    if not items:
        print(f"nothing to delete in {workdir}", file=sys.stderr)
        return 0
    if not args.yes and sys.stdin.isatty():
        answer = input(f"delete {what}? [y/N] ")
        if answer.strip().lower() not in ("y", "yes"):
            print("nothing deleted", file=sys.stderr)
            return 1
    removed = clean(workdir, steps, old)
    print(f"removed {len(removed)} item(s) ({total / 1e6:.1f} MB) from {workdir}", file=sys.stderr)
    return 0


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
    return confirm_and_clean(workdir, args.step or None, args.old, args)
