"""The package's import graph: go_core never imports the runner or the steps, and there is no cycle anywhere
in go_core, go_pipeline or the steps (imports inside functions count:
a cycle through a lazy import is still two modules that need each other)."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# source folder -> the package name it is installed as (steps/ is installed as go_pipeline.steps, setup.py)
PACKAGES = {"go_core": "go_core", "go_pipeline": "go_pipeline", "steps": "go_pipeline.steps"}


def _module_name(path: Path, folder: str) -> str:
    rel = path.relative_to(REPO / folder).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join((PACKAGES[folder], *parts))


def _modules(*folders: str) -> dict[str, Path]:
    return {
        _module_name(p, folder): p
        for folder in folders or tuple(PACKAGES)
        for p in sorted((REPO / folder).rglob("*.py"))
        if not (folder == "go_pipeline" and "steps" in p.relative_to(REPO / folder).parts)
    }


def _imports(path: Path, module: str) -> set[str]:
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1])
                mod = f"{base}.{node.module}" if node.module else base
            else:
                mod = node.module or ""
            names.add(mod)
            names.update(f"{mod}.{a.name}" for a in node.names)
    return names


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {m: {i for i in _imports(p, m) if i in modules and i != m} for m, p in modules.items()}


def _offending(folder: str, forbidden: tuple[str, ...]) -> list[str]:
    def bad(name: str) -> bool:
        return name.split(".")[0] == "steps" or any(
            name == f or name.startswith(f + ".") for f in forbidden if f != "steps"
        )

    return [f"{m} imports {i}" for m, p in _modules(folder).items() for i in sorted(_imports(p, m)) if bad(i)]


def test_go_core_imports_nothing_from_the_runner_or_the_steps():
    assert _offending("go_core", ("go_pipeline", "steps")) == []


def test_the_scan_sees_every_package():
    modules = _modules()
    for name in (
        "go_core.poses.check",
        "go_core.coarse.loop",
        "go_pipeline.runner",
        "go_pipeline.steps.coarse",
    ):
        assert name in modules
    assert any(i.startswith("go_pipeline.steps") for i in _graph()["go_pipeline.steps.coarse"])


def _find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return stack[stack.index(n) :] + [n]
            if n not in state and (found := visit(n)):
                return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_the_import_graph_is_acyclic():
    assert _find_cycle(_graph()) is None, " -> ".join(_find_cycle(_graph()) or [])


def test_the_cycle_finder_finds_a_cycle():
    assert _find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert _find_cycle({"a": {"b"}, "b": set()}) is None


def test_every_project_import_of_a_script_resolves():
    """benchmarks/ imports the package by name, outside the graph above: a module renamed
    in go_core must not leave a script that fails only when someone runs it."""
    modules = _modules()
    missing = []
    for script in sorted((REPO / "benchmarks").rglob("*.py")):
        if "results" in script.relative_to(REPO / "benchmarks").parts:
            continue  # frozen copies of the code that made a result
        for node in ast.walk(ast.parse(script.read_text(), filename=str(script))):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module]
                if isinstance(node, ast.ImportFrom) and not node.level and node.module
                else []
            )
            for name in names:
                installed = "go_pipeline." + name if name.split(".")[0] == "steps" else name
                if name.split(".")[0] in PACKAGES and installed not in modules:
                    missing.append(f"{script.relative_to(REPO)}:{node.lineno} imports {name}")
    assert not missing, "\n".join(missing)
