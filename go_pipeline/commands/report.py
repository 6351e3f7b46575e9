"""`go-pipeline report SCENE [--format json|md|html] [-o OUT] [--open]`: the run report of a scene's work dir.

The report refuses artifacts that come from different runs (a step made from another upstream artifact
than the one shown, e.g. after `run --until` or `clean`), unless `--allow-mixed` (then it says so first).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

FORMATS = {".json": "json", ".md": "md", ".html": "html", ".htm": "html"}


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("report", help="metrics, timings and images of a scene's run (json, md, html)")
    p.add_argument("scene", type=Path, help="scene folder")
    p.add_argument(
        "--format",
        choices=["json", "md", "html"],
        default=None,
        help="default: the suffix of -o FILE, else md (json without -o is printed)",
    )
    p.add_argument(
        "-o",
        "--out",
        type=Path,
        default=None,
        help="a file (report.html, report.md, report.json: the format follows the suffix) or a folder "
        "(default: WORKDIR/report/)",
    )
    p.add_argument("--workdir", metavar="W", help="where artifacts are (default: SCENE/.go)")
    p.add_argument("--pipeline", metavar="FILE", help="pipeline.yaml (for the step order)")
    p.add_argument(
        "--open",
        action="store_true",
        help="open the report in the default browser (without --format / -o: the html report)",
    )
    p.add_argument(
        "--allow-mixed",
        action="store_true",
        help="report even when the artifacts come from different runs (with a warning at the top)",
    )
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from go_core.errors import GoError
    from go_pipeline import store
    from go_pipeline.reporting.run_report import build_report

    wd = store.workdir_for(args.scene, args.workdir)
    if not (wd / "artifacts").is_dir():
        raise GoError("no artifacts yet: run `go-pipeline run` on this scene first", wd)
    out: Path | None = args.out
    as_file = out is not None and out.suffix.lower() in FORMATS
    fmt = args.format or (FORMATS[out.suffix.lower()] if as_file else ("html" if args.open else "md"))
    if args.open and fmt == "json" and out is None:
        raise GoError("--open: a json report without -o is printed, not written; use --format html")
    if as_file and FORMATS[out.suffix.lower()] != fmt:
        raise GoError(f"-o {out}: the suffix says {FORMATS[out.suffix.lower()]}, --format says {fmt}")
    report = build_report(args.scene, args.workdir, args.pipeline)
    from go_pipeline.outputs import published_outputs

    report["outputs"] = published_outputs(wd, store.current_manifests(wd))  # outputs/, not artifacts/<key>/
    if report["warnings"]:
        if not args.allow_mixed:
            raise GoError(
                "the artifacts come from different runs: "
                + "; ".join(report["warnings"][:3])
                + (f" (+{len(report['warnings']) - 3} more)" if len(report["warnings"]) > 3 else "")
                + f"; run `go-pipeline run {args.scene}` to bring them up to date, or --allow-mixed",
                wd,
            )
        for w in report["warnings"]:
            print(f"WARNING: mixed runs: {w}", file=sys.stderr)
    if fmt == "json":
        text = json.dumps(report, indent=2, sort_keys=True, allow_nan=False)
        if out is None:
            print(text)
            return 0
        from go_core.io.atomic import atomic_write_text, readable

        path = readable(atomic_write_text(out if as_file else out / "report.json", text + "\n"))
        print(path)
        if args.open:
            _open_in_browser(path)
        return 0
    from go_pipeline.reporting.render import write_html, write_markdown

    folder = (out.parent if as_file else out) if out is not None else wd / "report"
    path = (write_markdown if fmt == "md" else write_html)(report, folder)
    if as_file and path != out:
        path = path.replace(out)
    from go_core.io.atomic import readable

    print(readable(path))
    if args.open:
        _open_in_browser(path)
    return 0


def _open_in_browser(path: Path) -> None:
    """Open ``path`` with the desktop's browser; says so (one line) when there is none to open it."""
    import webbrowser

    if not webbrowser.open(path.resolve().as_uri()):
        print(f"note: no browser found to open {path}; open it yourself", file=sys.stderr)
