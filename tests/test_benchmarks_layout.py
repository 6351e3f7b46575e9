"""The benchmarks' layout (issue 82, item 2): a handful of maintained scripts at the top of benchmarks/, each
in its README; the experiments in benchmarks/archive/, in its index, imported by no test; the repair prior's
corpus and training together in benchmarks/prior/, outside the installed package."""

from __future__ import annotations

import ast
from pathlib import Path

from setuptools import find_packages

REPO = Path(__file__).resolve().parents[1]
BENCHMARKS = REPO / "benchmarks"
ARCHIVE = BENCHMARKS / "archive"
MAX_SCRIPTS = 12
# the folders whose packages benchmarks/ imports by their own name (a script's folder is on sys.path)
LOCAL_PACKAGES = {"_lib": BENCHMARKS / "_lib", "corpus": BENCHMARKS / "prior" / "corpus"}


def top_level_scripts() -> list[str]:
    return sorted(p.name for p in BENCHMARKS.iterdir() if p.is_file() and p.suffix in (".py", ".sh"))


def _docstrings(tree: ast.AST) -> set[int]:
    """The ids of the docstring nodes of a module, its classes and functions."""
    kinds = (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)
    return {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, kinds) and node.body and isinstance(node.body[0], ast.Expr)
    }


def _imported(tree: ast.AST) -> list[str]:
    """Every module name an ``import`` or an absolute ``from ... import`` names."""
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            names.append(node.module)
    return names


def archive_uses(source: str, archived: set[str]) -> list[str]:
    """What in ``source`` (a test file) reaches an archived script: an import of one by its name, or a
    string (not a docstring) that names the archive folder (a path handed to ``benchmark_module``, runpy,
    importlib or a subprocess)."""
    tree = ast.parse(source)
    found = [f"imports {n}" for n in _imported(tree) if n.split(".")[0] in archived]
    skip = _docstrings(tree)
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip:
            if "archive/" in node.value or node.value == "archive":
                found.append(f"line {node.lineno} names {node.value!r}")
    return found


def test_at_most_twelve_top_level_scripts():
    scripts = top_level_scripts()
    assert len(scripts) <= MAX_SCRIPTS, scripts


def test_every_script_is_in_its_readme():
    readme = (BENCHMARKS / "README.md").read_text()
    assert [s for s in top_level_scripts() if f"`{s}`" not in readme] == []
    index = (ARCHIVE / "README.md").read_text()
    assert [p.name for p in sorted(ARCHIVE.glob("*.py")) if f"`{p.name}`" not in index] == []


def test_no_test_imports_an_archived_script():
    archived = {p.stem for p in ARCHIVE.glob("*.py")}
    found = {
        path.name: uses
        for path in sorted((REPO / "tests").rglob("*.py"))
        if path.name != Path(__file__).name  # this file names the archive to test the check
        and (uses := archive_uses(path.read_text(), archived))
    }
    assert found == {}


def test_the_archive_check_sees_imports_and_paths():
    archived = {"chaos", "coarse_dev"}
    source = '"""Docs may name benchmarks/archive/chaos.py."""\nimport chaos\nfrom coarse_dev import DEV\n'
    assert archive_uses(source, archived) == ["imports chaos", "imports coarse_dev"]
    source = 'def f():\n    """benchmarks/archive/x.py"""\n    return benchmark_module("archive/chaos")\n'
    assert archive_uses(source, archived) == ["line 3 names 'archive/chaos'"]
    assert archive_uses("import numpy\nfrom go_core import render\n", archived) == []


def test_the_corpus_is_not_in_the_installed_package():
    assert not (REPO / "go_core" / "corpus").exists()
    packages = find_packages(str(REPO), include=["go_core", "go_core.*", "go_pipeline", "go_pipeline.*"])
    assert "go_core" in packages and not [p for p in packages if "corpus" in p.split(".")]
    sources = [p for folder in ("go_core", "go_pipeline", "steps") for p in (REPO / folder).rglob("*.py")]
    users = [
        f"{p.relative_to(REPO)} imports {n}"
        for p in sources
        for n in _imported(ast.parse(p.read_text()))
        if n.split(".")[0] == "corpus" or n.startswith("go_core.corpus")
    ]
    assert users == []


def test_every_import_of_a_benchmarks_package_resolves():
    """``_lib.X`` and ``corpus.X`` (the folders beside the scripts) name a module that exists."""
    missing = []
    for script in sorted(BENCHMARKS.rglob("*.py")):
        if "results" in script.relative_to(BENCHMARKS).parts:
            continue  # frozen copies of the code that made a result
        for name in _imported(ast.parse(script.read_text())):
            top, _, rest = name.partition(".")
            if top in LOCAL_PACKAGES:
                target = LOCAL_PACKAGES[top].joinpath(*rest.split(".")) if rest else LOCAL_PACKAGES[top]
                if not (target.with_suffix(".py").is_file() or (target / "__init__.py").is_file()):
                    missing.append(f"{script.relative_to(REPO)} imports {name}")
    assert missing == []
