"""``go-pipeline params [SCENE] [--diff OTHER]``: every param with its default and current value (like
``dvc params``), or the params that differ between two work dirs / scenes.

Current values: with SCENE, its remembered settings (params.yaml) changed by any --profile / --set / --seed
given, i.e. what a plain ``run`` would use; without SCENE, the defaults changed by the flags. ``--diff``
compares what the two work dirs' current artifacts were made with (their manifests; a step without an
artifact: its settings).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from go_pipeline.commands._common import add_pipeline_args


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("params", help="list every param (default, current value), or diff two runs")
    p.add_argument("scene", nargs="?", help="scene folder (default: show pipeline.yaml's defaults)")
    p.add_argument(
        "--diff",
        metavar="OTHER",
        help="another scene folder or work dir: show only the params whose values differ",
    )
    p.add_argument("--changed", action="store_true", help="only params whose value is not the default")
    p.add_argument("--json", action="store_true", help="print JSON")
    add_pipeline_args(p)
    p.set_defaults(func=main)


def _workdir_of(path: str | Path, workdir: str | None = None) -> Path:
    """A scene folder's work dir, or ``path`` itself when it is a work dir (holds artifacts/ or refs/)."""
    from go_pipeline import store

    p = Path(path)
    if workdir is None and ((p / "artifacts").is_dir() or (p / "refs").is_dir()):
        return p.resolve()
    return store.workdir_for(p, workdir)


def current_params(pipeline, workdir: Path | None, settings) -> tuple[dict[str, dict[str, Any]], str]:
    """(step -> params, where they come from): the params the work dir's current artifacts were made with
    (steps without an artifact: from the settings), or the settings resolved."""
    resolved = pipeline.resolve_params(settings.profile, settings.sets)
    if workdir is None:
        return resolved, "settings"
    from go_pipeline import store

    made = {step: m.get("params", {}) for step, m in store.current_manifests(workdir).items()}
    if not made:
        return resolved, "settings"
    return {step: made.get(step, resolved[step]) for step in pipeline.steps}, "artifacts"


def _settings_for(args: argparse.Namespace, workdir: Path | None):
    from go_pipeline.commands._common import settings_from
    from go_pipeline.workspace import Settings

    if workdir is None:
        from go_pipeline.commands._common import overrides_from

        return Settings(args.profile, overrides_from(args), args.seed or 0)
    return settings_from(args, workdir)[1]


def _own(pipeline, step: str, params: dict[str, dict[str, Any]]) -> list[str]:
    """A step's own params (not another step's params given to it: those are listed under that step)."""
    return [n for n in params[step] if n not in pipeline.steps[step].upstream_params]


def _show(v: Any) -> str:
    return json.dumps(v) if not isinstance(v, str) else repr(v)


def main(args: argparse.Namespace) -> int:
    from go_core.errors import GoError
    from go_pipeline.pipeline import load_pipeline

    pipeline = load_pipeline(args.pipeline)
    defaults = pipeline.resolve_params(None, None)
    workdir = _workdir_of(args.scene, args.workdir) if args.scene else None
    if args.scene and not Path(args.scene).is_dir():
        raise GoError("scene folder not found", args.scene)
    settings = _settings_for(args, workdir)
    # listing: the values a run would use now; --diff: what each work dir's results were made with
    current = pipeline.resolve_params(settings.profile, settings.sets)
    if args.diff:
        current, _ = current_params(pipeline, workdir, settings)
    rows: list[dict[str, Any]] = []
    if args.diff:
        if not Path(args.diff).is_dir():
            raise GoError("not a folder (give a scene folder or a work dir)", args.diff)
        other_wd = _workdir_of(args.diff)
        from go_pipeline.workspace import Settings, load_settings

        other, _ = current_params(pipeline, other_wd, load_settings(other_wd) or Settings())
        for step in pipeline.steps:
            for name in _own(pipeline, step, defaults):
                a, b = current[step].get(name), other[step].get(name)
                if a != b:
                    rows.append({"param": f"{step}.{name}", "this": a, "other": b})
        if args.json:
            print(json.dumps(rows, indent=2))
            return 0
        if not rows:
            print(f"no param differs between {args.scene} and {args.diff}")
            return 0
        _table(
            ["param", str(args.scene), str(args.diff)], [[r["param"], r["this"], r["other"]] for r in rows]
        )
        return 0
    for step in pipeline.steps:
        for name in _own(pipeline, step, defaults):
            default = defaults[step][name]
            value = current[step].get(name, default)
            if args.changed and value == default:
                continue
            rows.append({"param": f"{step}.{name}", "default": default, "current": value})
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    _table(
        ["param", "default", "current"],
        [[r["param"], r["default"], "=" if r["current"] == r["default"] else r["current"]] for r in rows],
    )
    if settings.profile or settings.sets:
        sets = ", ".join(f"{k}={v}" for k, v in settings.sets.items()) or "none"
        print(f"(profile {settings.profile or '(none)'}, seed {settings.seed}, --set {sets})")
    return 0


def _table(head: list[str], rows: list[list[Any]]) -> None:
    cells = [
        [c if isinstance(c, str) and i == 0 else (c if c == "=" else _show(c)) for i, c in enumerate(r)]
        for r in rows
    ]
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h) for i, h in enumerate(head)]
    print("  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)).rstrip())
    for r in cells:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())
