"""Typed settings: a dataclass per component (as gsplat's ``DefaultStrategy``), its fields checked by type
and range when built from untyped values (pipeline.yaml, ``--set``, a JSON file).

    @dataclass
    class HullSettings:
        num_points: int = setting(20_000, ge=1, doc="points sampled inside the hull")
        init: Literal["hull", "random"] = "hull"

    from_mapping(HullSettings, {"num_points": "5"})   # SettingError: num_points: expected int, got str

Types: ``bool``, ``int``, ``float`` (an int is accepted; YAML's ``1e-3`` string too), ``str``,
``Literal[...]`` (choices), ``list[T]`` / ``tuple[T, ...]`` / ``tuple[T, T]``, ``T | None`` and nested
settings dataclasses. Ranges: ``ge``/``gt``/``le``/``lt`` bounds and ``multiple_of`` on numbers (on each
element of a list), ``length`` on lists. Cross-field rules go in the class's ``check()`` method, which
returns a list of problems.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping
from dataclasses import MISSING, Field
from functools import cache
from typing import Any, Literal, TypeVar, Union, get_args, get_origin

T = TypeVar("T")


class SettingError(ValueError):
    """A value that does not fit its setting; ``name`` is the setting's dotted name."""

    def __init__(self, name: str, problem: str) -> None:
        self.name, self.problem = name, problem
        super().__init__(f"{name}: {problem}" if name else problem)


def setting(
    default: Any = MISSING,
    *,
    default_factory: Any = MISSING,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    lt: float | None = None,
    multiple_of: int | None = None,
    length: int | None = None,
    doc: str = "",
) -> Any:
    """A dataclass field with its allowed range (checked by ``from_mapping`` / ``check_settings``)."""
    meta = {"ge": ge, "gt": gt, "le": le, "lt": lt, "multiple_of": multiple_of, "length": length, "doc": doc}
    meta = {k: v for k, v in meta.items() if v not in (None, "")}
    if default_factory is not MISSING:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    if isinstance(default, (list, dict, set)):
        value = default
        return dataclasses.field(default_factory=lambda: type(value)(value), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


@cache
def field_types(cls: type) -> dict[str, Any]:
    """Resolved annotations of a settings dataclass (string annotations evaluated in its module)."""
    return typing.get_type_hints(cls)


def type_name(tp: Any) -> str:
    origin = get_origin(tp)
    if origin is Literal:
        return " | ".join(repr(a) for a in get_args(tp))
    if origin in (Union, types.UnionType):
        return " | ".join(type_name(a) for a in get_args(tp))
    if origin in (list, tuple):
        inner = ", ".join(type_name(a) if a is not ... else "..." for a in get_args(tp))
        return f"{origin.__name__}[{inner}]"
    if tp is type(None):
        return "null"
    return getattr(tp, "__name__", str(tp))


def _value_name(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, (list, tuple)):
        return "list"
    if isinstance(value, Mapping):
        return "mapping"
    return type(value).__name__


def convert(tp: Any, value: Any, name: str) -> Any:
    """``value`` as type ``tp`` (an int as a float, a list as a tuple), or SettingError."""
    origin = get_origin(tp)
    if tp is Any:
        return value
    if origin is Literal:
        if value in get_args(tp) and type(value) in {type(a) for a in get_args(tp)}:
            return value
        raise SettingError(name, f"must be one of {type_name(tp)}, got {value!r}")
    if origin in (Union, types.UnionType):
        args = get_args(tp)
        if value is None and type(None) in args:
            return None
        problems = []
        for a in args:
            if a is type(None):
                continue
            try:
                return convert(a, value, name)
            except SettingError as e:
                problems.append(e.problem)
        problem = problems[0] if len(problems) == 1 else f"expected {type_name(tp)}, got {value!r}"
        raise SettingError(name, problem)
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise SettingError(name, f"expected {type_name(tp)}, got {_value_name(value)}")
        args = get_args(tp)
        if origin is tuple and args and args[-1] is not ...:
            if len(value) != len(args):
                raise SettingError(name, f"expected {len(args)} values, got {len(value)}")
            items = [convert(a, v, f"{name}[{i}]") for i, (a, v) in enumerate(zip(args, value, strict=True))]
        else:
            item = args[0] if args else Any
            items = [convert(item, v, f"{name}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, Mapping):
            raise SettingError(name, f"expected a mapping of {tp.__name__}, got {_value_name(value)}")
        return from_mapping(tp, value, prefix=f"{name}.")
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise SettingError(name, f"expected bool, got {_value_name(value)} {value!r}")
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise SettingError(name, f"expected int, got {_value_name(value)} {value!r}")
    if tp is float:
        if isinstance(value, str):  # YAML 1.1 reads 1e-3 (no dot) as a string
            try:
                value = float(value)
            except ValueError:
                raise SettingError(name, f"expected float, got str {value!r}") from None
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = float(value)
            if not math.isfinite(value):
                raise SettingError(name, "must be a finite number")
            return value
        raise SettingError(name, f"expected float, got {_value_name(value)} {value!r}")
    if tp is str:
        if isinstance(value, str):
            return value
        raise SettingError(name, f"expected str, got {_value_name(value)} {value!r}")
    if isinstance(tp, type) and isinstance(value, tp):
        return value
    raise SettingError(name, f"expected {type_name(tp)}, got {_value_name(value)}")


def check_range(f: Field, value: Any, name: str) -> None:
    """The field's bounds, ``multiple_of`` and ``length`` (bounds apply to every number of a list)."""
    meta = f.metadata
    if "length" in meta and isinstance(value, (list, tuple)) and len(value) != meta["length"]:
        raise SettingError(name, f"expected {meta['length']} values, got {len(value)}")
    numbers = value if isinstance(value, (list, tuple)) else [value]
    for x in numbers:
        if not isinstance(x, (int, float)) or isinstance(x, bool):
            continue
        for key, ok, word in (
            ("ge", lambda a, b: a >= b, ">="),
            ("gt", lambda a, b: a > b, ">"),
            ("le", lambda a, b: a <= b, "<="),
            ("lt", lambda a, b: a < b, "<"),
        ):
            if key in meta and not ok(x, meta[key]):
                raise SettingError(name, f"must be {word} {meta[key]}, got {x!r}")
        if "multiple_of" in meta and x % meta["multiple_of"]:
            raise SettingError(name, f"must be a multiple of {meta['multiple_of']}, got {x!r}")


def fields_of(cls: type) -> dict[str, Field]:
    return {f.name: f for f in dataclasses.fields(cls) if f.init}


def check_value(cls: type, key: str, value: Any, name: str | None = None) -> Any:
    """One setting of ``cls`` converted to its type and checked against its range (SettingError if not)."""
    fields = fields_of(cls)
    name = name or key
    if key not in fields:
        raise SettingError(name, f"unknown setting (known: {', '.join(fields) or 'none'})")
    value = convert(field_types(cls)[key], value, name)
    check_range(fields[key], value, name)
    return value


def from_mapping(cls: type[T], values: Mapping[str, Any], prefix: str = "") -> T:
    """An instance of the settings dataclass ``cls``: every key must be a field, every value of its type and
    in its range; fields not given keep their defaults. Runs the class's ``check()`` (cross-field rules)."""
    kwargs = {k: check_value(cls, k, v, f"{prefix}{k}") for k, v in values.items()}
    obj = cls(**kwargs)
    problems = obj.check() if hasattr(obj, "check") else []
    if problems:
        raise SettingError(prefix.rstrip("."), problems[0])
    return obj


def to_mapping(obj: Any) -> dict[str, Any]:
    """A settings dataclass as plain JSON-able data (tuples as lists), for cache keys and manifests."""

    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        return v

    return plain(obj)


def check_settings(obj: Any) -> list[str]:
    """Every range problem of an already built settings object (e.g. made in code with bad values)."""
    problems = []
    for name, f in fields_of(type(obj)).items():
        try:
            check_range(f, getattr(obj, name), name)
        except SettingError as e:
            problems.append(str(e))
    if hasattr(obj, "check"):
        problems.extend(obj.check())
    return problems
