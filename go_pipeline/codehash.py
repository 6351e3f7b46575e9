"""The code a step runs, as file hashes for its cache key (DVC's "code in the stage hash").

A step's code = its own module, every module of the step package (``go_pipeline.steps``) and of ``go_core``
that it imports, transitively (imports inside functions count: they are code the step may run), the
``__init__.py`` of every package on the way (importing ``go_core.render.cpu`` runs its ``__init__``),
and the native sources a module declares in a module-level literal ``NATIVE_SOURCES`` (paths relative to
that module's folder: the C++ kernels the CPU extension is compiled from).

Imports under ``if TYPE_CHECKING:`` are left out (they never run: the steps import their params classes
there, so editing steps/params.py reruns nothing by itself; the values are in the keys). Everything is found
with ``ast`` on the source files, nothing is imported, so ``status`` and a no-op ``run``
stay cheap. Third-party libraries are not followed (their versions are recorded in the manifest).

Files are named by their place in the package, e.g. ``go_core/coarse/losses.py``,
``go_pipeline/steps/coarse.py``, ``go_core/render/csrc/rasterize.cpp`` (the same names whether installed
editable or from a wheel).
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from go_core.errors import PipelineError

TRACKED_PACKAGES = ("go_core", "go_pipeline.steps")
NATIVE_SOURCES_NAME = "NATIVE_SOURCES"


@dataclass(frozen=True)
class CodeFingerprint:
    """``files``: {package path: sha256} of every file the step runs; ``digest``: one hash of them."""

    files: dict[str, str]
    digest: str


@cache
def _root_location(root: str) -> Path:
    """The folder of a tracked package, or the file of a tracked top-level module (imports at most the
    package's own ``__init__``, as importing the step itself would)."""
    try:
        spec = importlib.util.find_spec(root)
    except (ImportError, ValueError):
        spec = None
    if spec is not None and spec.submodule_search_locations:
        return Path(next(iter(spec.submodule_search_locations))).resolve()
    if spec is not None and spec.origin and spec.origin.endswith(".py"):
        return Path(spec.origin).resolve()
    raise PipelineError(f"module {root!r} not found (needed to hash the steps' code)")


def _roots_for(step_module: str) -> tuple[str, ...]:
    """go_core, the step package, and the step module's own package (a pipeline.yaml may name steps
    outside go_pipeline.steps)."""
    own = step_module.rpartition(".")[0] or step_module
    return tuple(dict.fromkeys((*TRACKED_PACKAGES, own)))


def _tracked_root(module: str, roots: tuple[str, ...]) -> str | None:
    best = None
    for root in roots:
        if (module == root or module.startswith(root + ".")) and (best is None or len(root) > len(best)):
            best = root
    return best


def _module_file(module: str, roots: tuple[str, ...]) -> Path | None:
    """The source file of a tracked module (``a/b.py`` or ``a/b/__init__.py``); None if there is none."""
    root = _tracked_root(module, roots)
    if root is None:
        return None
    location = _root_location(root)
    if location.is_file():
        return location if module == root else None
    rel = module[len(root) :].lstrip(".").split(".") if module != root else []
    base = location.joinpath(*rel) if rel else location
    if rel and base.with_suffix(".py").is_file():
        return base.with_suffix(".py")
    init = base / "__init__.py"
    return init if init.is_file() else None


def _display_name(module: str, path: Path) -> str:
    return module.replace(".", "/") + ("/__init__.py" if path.name == "__init__.py" else ".py")


def _package_of(module: str, path: Path) -> str:
    """The package a relative import in ``module`` (whose file is ``path``) is relative to."""
    return module if path.name == "__init__.py" else module.rpartition(".")[0]


def _parse(path: Path, package: str) -> tuple[tuple[str, ...], tuple[str, ...], str]:
    """(imported module names, declared native sources, sha256) of one source file."""
    data = path.read_bytes()
    digest = hashlib.sha256(data).hexdigest()
    imports, native = _parse_source(data, digest, path, package)
    return imports, native, digest


@cache
def _parse_source(
    data: bytes, digest: str, path: Path, package: str
) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Parsing is the costly part: cached per content (``digest``) for the life of the process."""
    try:
        tree = ast.parse(data, filename=str(path))
    except SyntaxError as e:
        problem = f"cannot parse it to hash the step's code: {e.msg} (line {e.lineno})"
        raise PipelineError(problem, path) from None
    skipped = {
        id(n)
        for block in ast.walk(tree)
        if isinstance(block, ast.If) and ast.unparse(block.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING")
        for stmt in block.body
        for n in ast.walk(stmt)
    }  # imports for type checking only never run
    names: list[str] = []
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Import):
            names.extend(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1])
                mod = f"{base}.{node.module}" if node.module else base
            else:
                mod = node.module or ""
            names.append(mod)
            # `from pkg import sub` may name a submodule
            names.extend(f"{mod}.{a.name}" for a in node.names if a.name != "*")
    native: list[str] = []
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == NATIVE_SOURCES_NAME for t in node.targets
        ):
            value = ast.literal_eval(node.value)
            native.extend(str(v) for v in value)
    return tuple(names), tuple(native)


def _parents(module: str) -> list[str]:
    parts = module.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def code_files(module: str) -> dict[str, str]:
    """{package path: sha256} of the step module and everything tracked that it imports, transitively."""
    roots = _roots_for(module)
    files: dict[str, str] = {}
    seen: set[str] = set()
    stack = [module]
    while stack:
        mod = stack.pop()
        if mod in seen:
            continue
        seen.add(mod)
        path = _module_file(mod, roots)
        if path is None:
            continue  # a name from `from pkg import func`, or an untracked module
        imports, native, digest = _parse(path, _package_of(mod, path))
        files[_display_name(mod, path)] = digest
        folder = _display_name(mod, path).rsplit("/", 1)[0]
        for rel in native:
            src = (path.parent / rel).resolve()
            try:
                data = src.read_bytes()
            except OSError as e:
                problem = f"native source {rel!r} cannot be read ({e.strerror or e})"
                raise PipelineError(problem, path) from None
            files[_normalise(f"{folder}/{rel}")] = hashlib.sha256(data).hexdigest()
        stack.extend(p for p in _parents(mod) if _tracked_root(p, roots))
        stack.extend(m for m in imports if _tracked_root(m, roots))
    return dict(sorted(files.items()))


def _normalise(name: str) -> str:
    parts: list[str] = []
    for p in name.split("/"):
        if p == "..":
            parts.pop()
        elif p not in ("", "."):
            parts.append(p)
    return "/".join(parts)


def digest_of(files: dict[str, str]) -> str:
    """One hash of a ``code`` map (what the cache key holds; the manifest keeps the map itself)."""
    h = hashlib.sha256()
    for name in sorted(files):
        h.update(name.encode("utf-8") + b"\0" + files[name].encode("ascii") + b"\n")
    return h.hexdigest()


def fingerprint(module: str) -> CodeFingerprint:
    files = code_files(module)
    return CodeFingerprint(files, digest_of(files))


def changed_files(old: dict[str, str] | None, new: dict[str, str]) -> list[str]:
    """Names of the files that differ (changed, added or removed) between two ``code`` maps, sorted."""
    old = old or {}
    return sorted(n for n in set(old) | set(new) if old.get(n) != new.get(n))
