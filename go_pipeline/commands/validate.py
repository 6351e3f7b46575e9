"""``go-pipeline validate SCENE``: check a scene folder; print what it holds, or every problem found."""

from __future__ import annotations

import argparse
import json
import sys


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "validate", help="check a scene folder and print what it holds or every problem"
    )
    p.add_argument("scene", help="scene folder (NeRF-synthetic, COLMAP, or a folder of photos)")
    p.add_argument("--views", type=int, default=0, help="choose N training views (0: the scene's own split)")
    p.add_argument("--max-size", type=int, default=0, help="downscale so the longest side is at most this")
    p.add_argument("--json", action="store_true", help="print the findings as JSON")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from go_core.scene.validate import validate_scene

    report = validate_scene(args.scene, views=args.views, max_size=args.max_size)
    if args.json:
        print(
            json.dumps(
                {
                    "path": str(report.path),
                    "ok": report.ok,
                    "problems": report.problems,
                    "facts": report.facts(),
                },
                indent=2,
            )
        )
    else:
        print(report.summary(), file=sys.stdout if report.ok else sys.stderr)
    return 0 if report.ok else 2
