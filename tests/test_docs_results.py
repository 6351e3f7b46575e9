"""Docs quote measured figures from benchmarks/results/*.json: every result file they name exists, and every
figure in a table that cites one is in that JSON (issue 31: docs say what is, with the JSON it came from).

A table cites the JSON files named in the text between it and the heading or table before it, and in its
own cells (bare names resolve under benchmarks/results/). Every decimal figure of its body (the first
column is the row's label) must be one of:

* a number of the cited JSON files, rounded as shown (when the row's label is a key of the JSON, such as a
  scene name, only the numbers under that key count), or the mean of one of their number lists;
* the difference of two figures of the same row (a "− exact" or "full − coarse" column);
* in a row labelled "mean ...", the mean of the figures at the same place in the rows above.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RESULTS = "benchmarks/results/"
NAMED = re.compile(r"benchmarks/results/[A-Za-z0-9_./-]+\.(?:json|md)")  # a file a doc names
CITED = re.compile(r"(?:benchmarks/results/[A-Za-z0-9_./*-]+|(?<![\w/.*-])[A-Za-z0-9_.-]+)\.json")
FIGURE = re.compile(r"(?<![\w.])[-−+]?\d+\.\d+(?![\w.])")


def _docs() -> list[Path]:
    return [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]


def _numbers(node, label: str | None = None, under: bool = False) -> Iterator[float]:
    """The numbers of a JSON document (with ``label``: only those under a key ``label``), and the mean of
    every list of numbers."""
    if isinstance(node, dict):
        for key, value in node.items():
            yield from _numbers(value, label, under or key == label)
    elif isinstance(node, list):
        plain = [v for v in node if isinstance(v, int | float) and not isinstance(v, bool)]
        if plain and (label is None or under):
            yield sum(plain) / len(plain)
        for value in node:
            yield from _numbers(value, label, under)
    elif isinstance(node, int | float) and not isinstance(node, bool) and (label is None or under):
        yield float(node)


def _keys(node) -> set[str]:
    if isinstance(node, dict):
        return set(node).union(*(_keys(v) for v in node.values()))
    if isinstance(node, list):
        return set().union(*(_keys(v) for v in node))
    return set()


def _tables(text: str) -> Iterator[tuple[int, str, list[list[str]]]]:
    """(line number, the text before it since the last heading or table, body rows as cells) per table."""
    lines = text.splitlines()
    caption: list[str] = []
    i = 0
    while i < len(lines):
        if lines[i].startswith("|"):
            j = i
            while j < len(lines) and lines[j].startswith("|"):
                j += 1
            rows = [[c.strip() for c in row.strip().strip("|").split("|")] for row in lines[i + 2 : j]]
            yield i + 1, "\n".join(caption), rows
            caption, i = [], j
            continue
        caption = [] if lines[i].startswith("#") else [*caption, lines[i]]
        i += 1


def _cited(text: str) -> list[Path]:
    """The result JSON files a text names (a bare name resolves under benchmarks/results/)."""
    files = set()
    for ref in CITED.findall(text):
        path = ref if ref.startswith(RESULTS) else RESULTS + ref
        if "*" in path or (REPO / path).is_file():
            files.update(REPO.glob(path))
    return sorted(files)


def _figures(cell: str) -> list[tuple[float, int]]:
    """(value, decimals) of the decimal figures in a cell."""
    return [(float(f.replace("−", "-")), len(f.split(".")[1])) for f in FIGURE.findall(cell)]


def _derived(value: float, decimals: int, row: list, column: list[float], label: str) -> bool:
    """A row difference, or (in a mean row) the mean of the column above (module docstring)."""
    unit = 10.0**-decimals + 1e-9
    values = [v for v, _ in row]
    pairs = ((a, b) for i, a in enumerate(values) for j, b in enumerate(values) if i != j)
    if any(abs(a - b - value) <= unit for a, b in pairs):
        return True
    return (
        label.lower().startswith(("mean", "dev mean"))
        and bool(column)
        and (abs(sum(column) / len(column) - value) <= unit)
    )


def table_problems(rows: list[list[str]], data: list) -> list[str]:
    """The figures of ``rows`` that the JSON documents ``data`` do not hold (module docstring)."""
    keys = set().union(*(_keys(d) for d in data))
    above: dict[tuple[int, int], list[float]] = {}
    problems = []
    for cells in rows:
        label = cells[0].strip("*` ")
        pool = [v for d in data for v in _numbers(d, label if label in keys else None)]
        figures = [_figures(c) for c in cells[1:]]
        row = [f for column in figures for f in column]
        for c, column in enumerate(figures):
            for k, (value, decimals) in enumerate(column):
                half = 0.5 * 10.0**-decimals + 1e-9
                found = any(abs(v - value) <= half for v in pool)
                if not found and not _derived(value, decimals, row, above.get((c, k), []), label):
                    problems.append(f"{label}: {value:.{decimals}f}")
                above.setdefault((c, k), []).append(value)
    return problems


def test_docs_name_only_result_files_that_exist():
    missing = []
    for doc in _docs():
        for ref in NAMED.findall(doc.read_text()):
            if not (REPO / ref).exists():
                missing.append(f"{doc.name}: {ref}")
    assert not missing


def test_figures_of_docs_tables_are_in_the_json_they_cite():
    problems, checked = [], 0
    for doc in _docs():
        for line, caption, rows in _tables(doc.read_text()):
            files = _cited(caption + "\n" + "\n".join(" ".join(r) for r in rows))
            if files:
                checked += 1
                data = [json.loads(p.read_text()) for p in files]
                problems += [f"{doc.name}:{line}: {p}" for p in table_problems(rows, data)]
    assert checked >= 10  # the docs' result tables are found
    assert not problems, "\n".join(problems)


def test_a_planted_wrong_figure_is_caught():
    data = [{"scenes": {"milk": {"psnr": 20.8712, "ssim": 0.86612}, "plate": {"psnr": 21.95, "ssim": 0.877}}}]
    rows = [["milk", "20.87 / 0.866", ""], ["plate", "21.95 / 0.877", ""], ["mean", "21.41 / 0.872"]]
    assert table_problems(rows, data) == []
    assert table_problems([["milk", "20.97 / 0.866"]], data) == ["milk: 20.97"]
    assert table_problems([["milk", "21.95 / 0.866"]], data) == ["milk: 21.95"]  # plate's, not milk's
    assert table_problems([*rows[:2], ["mean", "21.51 / 0.872"]], data) == ["mean: 21.51"]
