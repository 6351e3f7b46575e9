"""Every packaged step param's default is written in exactly one file: its params class (steps/params.py, or
the go_core settings class it extends). pipeline.yaml and the steps never restate it; library functions that
still restate one are listed in RESTATED (a ratchet: the list may only shrink)."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

from go_pipeline.steps.registry import STEPS, upstream_fields

from go_core.config import to_mapping

REPO = Path(__file__).resolve().parents[1]


def _spellings(value) -> list[str]:
    """How a default may be written: Python's repr and YAML's flow style."""
    if isinstance(value, bool):
        return [repr(value), str(value).lower()]
    if isinstance(value, (list, tuple)):
        return [repr(list(value)), repr(tuple(value)), "[" + ", ".join(map(str, value)) + "]"]
    if isinstance(value, str):
        return [repr(value), f'"{value}"'] + ([value] if value and " " not in value else [])
    return [repr(value)]


def _definition(name: str, value) -> re.Pattern:
    """``name: value`` (YAML), ``name: type = value`` / ``= setting(value`` (a field or a keyword default)
    or ``name = value``: the places where a default is written."""
    values = "|".join(re.escape(s) for s in _spellings(value))
    return re.compile(
        rf"(?m)^\s*(?:def .*\b)?{name}\s*(?::[^=\n]*)?[:=]\s*(?:setting\(\s*)?(?:{values})\s*(?:[,)#]|$)"
    )


def _files() -> list[Path]:
    return [
        REPO / "pipeline.yaml",
        *sorted((REPO / "steps").glob("*.py")),
        *sorted(REPO.glob("go_core/**/*.py")),
    ]


def _places(name: str, value) -> list[str]:
    pattern = _definition(name, value)
    return [str(p.relative_to(REPO)) for p in _files() if pattern.search(p.read_text(encoding="utf-8"))]


# keyword defaults of library functions that restate a param's default (to remove: the caller passes it)
RESTATED = {
    "views": {"go_core/scene/loader.py", "go_core/scene/validate.py"},  # 0: the scene's own split
    "poses": {"go_core/scene/artifact.py"},  # Ingest(): a record of how the scene step ingested
    "backend": {"go_core/poses/refine.py", "go_core/render/api.py"},  # "auto": the renderer's own choice
}

# same name and value, another meaning: a docstring example, the synthetic test scenes' SH degree
UNRELATED = {
    "init": {"go_core/config.py"},
    "sh_degree": {"go_core/render/synthetic.py"},
}


def _home(cls: type, name: str) -> str:
    """The file of the class in ``cls``'s MRO that defines the field ``name``."""
    import sys

    owner = next(c for c in cls.__mro__ if name in c.__dict__.get("__annotations__", {}))
    return str(Path(sys.modules[owner.__module__].__file__).resolve().relative_to(REPO)).replace(
        "go_pipeline/steps", "steps"
    )


def _restated() -> dict[str, set[str]]:
    """{param: files restating its default} outside the params classes (another step's params class that
    has a setting of the same name and value is that setting's own home, not a restatement)."""
    classes = [d.params for d in STEPS.values()]
    found: dict[str, set[str]] = {}
    for cls in classes:
        upstream, defaults = upstream_fields(cls), to_mapping(cls())
        for f in dataclasses.fields(cls):
            if f.name in upstream:
                continue
            homes = {_home(c, f.name) for c in classes if f.name in {g.name for g in dataclasses.fields(c)}}
            extra = set(_places(f.name, defaults[f.name])) - homes
            if extra:
                found.setdefault(f.name, set()).update(extra)
    return found


def test_no_param_default_is_written_twice():
    found = _restated()
    known = {n: RESTATED.get(n, set()) | UNRELATED.get(n, set()) for n in {*RESTATED, *UNRELATED}}
    new = {name: files - known.get(name, set()) for name, files in found.items()}
    assert {n: f for n, f in new.items() if f} == {}, "restated outside the params class"
    gone = {name: files - found.get(name, set()) for name, files in known.items()}
    assert {n: f for n, f in gone.items() if f} == {}, "no longer restated: remove it from RESTATED"


def test_the_finder_sees_a_default_written_twice():
    text = "coarse:\n  params:\n    iterations: 2500   # the budget\n"
    assert _definition("iterations", 2500).search(text)
    assert _definition("iterations", 2500).search("    iterations: int = setting(2500, ge=0, doc='x')\n")
    assert _definition("floaters", True).search("      floaters: true\n")
    assert not _definition("iterations", 2500).search("    iterations: 25000\n")
    assert _places("iterations", 2500) == ["go_core/coarse/settings.py"]  # only the class
    assert _home(STEPS["go_pipeline.steps.coarse"].params, "iterations") == "go_core/coarse/settings.py"
