"""``go-pipeline gc SCENE``: delete every artifact and checkpoint the latest run does not use (like
``dvc gc``), keeping each step's current artifact, the outputs, params.yaml and the logs.
``--dry-run`` lists what would go; on a terminal it asks first (``-y`` does not ask)."""

from __future__ import annotations

import argparse
from pathlib import Path

from go_pipeline.commands.clean import add_confirm_args, confirm_and_clean


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("gc", help="delete artifacts and checkpoints the latest run does not use")
    p.add_argument("scene", help="scene folder")
    p.add_argument("--workdir", metavar="W", help="the work dir (default: SCENE/.go)")
    add_confirm_args(p)
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from go_core.errors import GoError
    from go_pipeline import store

    if not Path(args.scene).is_dir():
        raise GoError("scene folder not found", args.scene)
    return confirm_and_clean(store.workdir_for(args.scene, args.workdir), None, True, args)
