"""The ``go-pipeline`` command. Subcommands are modules of ``go_pipeline.commands`` exposing
``add_parser(subparsers)`` (which sets ``func=main``) and ``main(args) -> int``.

Only the module of the subcommand being run is imported (so a no-op ``run`` stays fast); ``--help``
imports them all. A GoError prints one line ``error: <file>: <problem>`` and exits 2 (a crashed step
exits 1); ``--debug`` adds the traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys

from go_pipeline.openmp import set_default_wait

CORE_COMMANDS = ("run", "status", "clean", "validate")


def command_names() -> list[str]:
    import go_pipeline.commands as pkg

    found = sorted(m.name for m in pkgutil.iter_modules(pkg.__path__) if not m.name.startswith("_"))
    return [c for c in CORE_COMMANDS if c in found] + [c for c in found if c not in CORE_COMMANDS]


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    from go_pipeline import __version__

    parser = argparse.ArgumentParser(
        prog="go-pipeline",
        description="GaussianObject: reconstruction from a few masked, posed photos (a DAG of cached steps).",
    )
    parser.add_argument("--version", action="version", version=f"go-pipeline {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in command_names():
        if only is not None and name != only:
            continue
        module = importlib.import_module(f"go_pipeline.commands.{name}")
        before = set(sub.choices)
        module.add_parser(sub)
        for new in set(sub.choices) - before:
            try:
                sub.choices[new].add_argument("--debug", action="store_true", help="show tracebacks")
            except argparse.ArgumentError:
                pass
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    set_default_wait(os.environ)  # before torch loads libgomp (--in-process steps)
    debug = "--debug" in argv
    first = next((a for a in argv if not a.startswith("-")), None)
    only = first if first in command_names() else None
    try:
        parser = build_parser(only)
        args = parser.parse_args(argv)
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return _closed_pipe()
    except Exception as e:  # noqa: BLE001 - the one place that turns errors into exit codes
        from go_core.errors import GoError

        if not isinstance(e, GoError):
            raise
        if debug:
            import traceback

            traceback.print_exc()
        print(f"error: {e}", file=sys.stderr)
        return int(getattr(e, "exit_code", 2))


def _closed_pipe() -> int:
    """The reader of our output went away (``... | head``): stop quietly, as a killed-by-SIGPIPE command
    would (exit 141), without a traceback from the interpreter's final flush of stdout."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
    return 141


if __name__ == "__main__":
    sys.exit(main())
