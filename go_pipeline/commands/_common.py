"""Arguments shared by several subcommands."""

from __future__ import annotations

import argparse
from typing import Any


def add_pipeline_args(p: argparse.ArgumentParser, params: bool = True) -> None:
    p.add_argument("--workdir", metavar="W", help="where artifacts go (default: SCENE/.go)")
    p.add_argument("--pipeline", metavar="FILE", help="pipeline.yaml to use (default: the packaged one)")
    p.add_argument(
        "--allow-custom-steps",
        action="store_true",
        default=None,
        help="a pipeline file is code: let its steps name functions outside the installed steps "
        "(go_pipeline.steps.*); only for pipeline files you trust",
    )
    if params:
        p.add_argument("--profile", metavar="NAME", help="named param overrides from pipeline.yaml profiles")
        p.add_argument(
            "--set",
            dest="sets",
            action="append",
            default=[],
            metavar="STEP.PARAM=VALUE",
            help="override a param (YAML value, type-checked); repeatable",
        )
        p.add_argument(
            "--seed",
            type=int,
            default=None,
            help="random seed, part of every cache key (default: the work dir's last, else 0)",
        )
        p.add_argument(
            "--reset-params",
            action="store_true",
            help="forget the work dir's remembered profile / --set / seed (params.yaml) and start from "
            "pipeline.yaml's defaults",
        )
        p.add_argument(
            "--allow-outside",
            action="store_true",
            help="let the scene's format files name images/masks outside the scene folder (absolute or "
            "'../' paths); they are then hashed into the cache key like the folder's own files",
        )


def overrides_from(args: argparse.Namespace) -> dict[str, Any]:
    from go_pipeline.pipeline import parse_set_argument

    overrides: dict[str, Any] = {}
    for text in args.sets:
        dotted, value = parse_set_argument(text)
        overrides[dotted] = value
    return overrides


def settings_from(args: argparse.Namespace, workdir, default_profile: str | None = None):
    """(remembered settings of the work dir or None, this invocation's settings): the remembered profile,
    --set values and seed of ``workdir/params.yaml`` changed by the flags given (go_pipeline.workspace)."""
    from go_pipeline.workspace import load_settings, merge

    saved = load_settings(workdir)
    settings = merge(
        saved,
        args.profile,
        overrides_from(args),
        args.seed,
        reset=args.reset_params,
        default_profile=default_profile,
    )
    return saved, settings
