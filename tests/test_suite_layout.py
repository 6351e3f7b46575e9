"""The test suite's own layout: every tests/test_*.py holds tests (pytest collects it as a test module);
helpers are named _*.py."""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def _has_tests(path: Path) -> bool:
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name.startswith("test"):
            return True
        if isinstance(node, ast.ClassDef) and node.name.startswith("Test"):
            return True
    return False


def test_every_test_module_holds_tests_and_helpers_hold_none():
    assert [p.name for p in sorted(TESTS.glob("test_*.py")) if not _has_tests(p)] == []
    assert [p.name for p in sorted(TESTS.glob("_*.py")) if p.name != "__init__.py" and _has_tests(p)] == []
