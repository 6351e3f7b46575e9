"""`go-pipeline report SCENE --format json|md|html`: the run report of a scene's work dir."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("report", help="metrics, timings and images of a scene's run (json, md, html)")
    p.add_argument("scene", type=Path, help="scene folder")
    p.add_argument("--format", choices=["json", "md", "html"], default="md")
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="json: file to write (default: print); md/html: folder (default WORKDIR/report)",
    )
    p.add_argument("--workdir", metavar="W", help="where artifacts are (default: SCENE/.go)")
    p.add_argument("--pipeline", metavar="FILE", help="pipeline.yaml (for the step order)")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from go_core.errors import GoError
    from go_pipeline import store
    from go_pipeline.reporting.run_report import build_report

    wd = store.workdir_for(args.scene, args.workdir)
    if not (wd / "artifacts").is_dir():
        raise GoError("no artifacts yet: run `go-pipeline run` on this scene first", wd)
    report = build_report(args.scene, args.workdir, args.pipeline)
    if args.format == "json":
        text = json.dumps(report, indent=2, sort_keys=True, allow_nan=False)
        if args.out is None:
            print(text)
        else:
            from go_core.io.atomic import atomic_write_text

            atomic_write_text(args.out, text + "\n")
            print(args.out)
        return 0
    from go_pipeline.reporting.render import write_html, write_markdown

    out_dir = args.out or (wd / "report")
    path = (write_markdown if args.format == "md" else write_html)(report, Path(out_dir))
    print(path)
    return 0
