"""The reference docs say what is; the history lives in decision records (issue 82).

* README.md and docs/*.md (the top level of docs/, not docs/decisions/) name no commit hash and no date:
  dates and commit hashes live in docs/decisions/ and in the result JSONs.
* The README is at most 120 lines.
* Every decision record docs/decisions/NNNN-title.md has its four parts (context, decision, evidence with
  at least one result JSON that exists, date) and is listed in docs/decisions/README.md.
"""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DECISIONS = REPO / "docs" / "decisions"
README_MAX_LINES = 120

# A commit hash: 7 to 40 lowercase hex digits, standing alone, with at least one digit and one letter a-f
# (so figures such as 0.0236 or 2500 and words such as "deadbeef" or "facade" are not hashes).
HASH = re.compile(r"(?<![\w.-])(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}(?![\w-])")
DATE = re.compile(r"2026-")
RECORD_NAME = re.compile(r"^\d{4}-[a-z0-9-]+\.md$")
PARTS = ("## Context", "## Decision", "## Evidence", "## Date")
RESULT = re.compile(r"benchmarks/results/[A-Za-z0-9_./-]+\.json")
ISO_DATE = re.compile(r"\b20\d\d-\d\d-\d\d\b")


def reference_docs() -> list[Path]:
    return [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]


def history_marks(text: str) -> list[str]:
    """The commit hashes and dates of ``text``, each as 'line N: mark'."""
    marks = []
    for n, line in enumerate(text.splitlines(), 1):
        marks += [f"line {n}: {m}" for m in HASH.findall(line)]
        marks += [f"line {n}: {line[m.start() : m.start() + 10]}" for m in DATE.finditer(line)]
    return marks


def record_problems(path: Path) -> list[str]:
    """What a decision record lacks (module docstring)."""
    text = path.read_text()
    problems = [f"{path.name}: no '{part}' section" for part in PARTS if part not in text]
    if not RECORD_NAME.match(path.name):
        problems.append(f"{path.name}: not named NNNN-title.md")
    evidence = text.split("## Evidence", 1)[-1].split("\n## ", 1)[0] if "## Evidence" in text else ""
    files = RESULT.findall(evidence)
    if not files:
        problems.append(f"{path.name}: its evidence names no benchmarks/results/*.json")
    problems += [f"{path.name}: {f} does not exist" for f in files if not (REPO / f).is_file()]
    date = text.split("## Date", 1)[-1] if "## Date" in text else ""
    if not ISO_DATE.search(date):
        problems.append(f"{path.name}: its date is not YYYY-MM-DD")
    return problems


def records() -> list[Path]:
    return sorted(p for p in DECISIONS.glob("*.md") if p.name != "README.md")


def test_reference_docs_hold_no_commit_hash_or_date():
    found = [f"{p.relative_to(REPO)}: {m}" for p in reference_docs() for m in history_marks(p.read_text())]
    assert not found, "\n".join(found)


def test_readme_is_at_most_120_lines():
    assert len((REPO / "README.md").read_text().splitlines()) <= README_MAX_LINES


def test_every_decision_record_has_its_four_parts_and_is_indexed():
    assert len(records()) >= 20
    index = (DECISIONS / "README.md").read_text()
    problems = [p for path in records() for p in record_problems(path)]
    problems += [f"{p.name} is not in docs/decisions/README.md" for p in records() if p.name not in index]
    assert not problems, "\n".join(problems)


def test_the_marks_found_are_hashes_and_dates_not_figures_or_words():
    assert history_marks("code 0fd721d, commit 2ceb1a7b3c") == ["line 1: 0fd721d", "line 1: 2ceb1a7b3c"]
    assert history_marks("measured 2026-11-29") == ["line 1: 2026-11-29"]
    assert history_marks("(`a689687`) and 1e71750.") == ["line 1: a689687", "line 1: 1e71750"]
    clean = (
        "0.0236 dB, 2500 iterations, 1600 px, deadbeef, facade, decade, 1e-10, 3e-8, 6 267 498 bytes, "
        "sha256 of 64 digits 873c4018c6316f4967c154761c7edf4ee38ceebfa349df6f510e90975295d1a1, "
        "go-repair-prior-4, realesr-animevideov3-x4, benchmarks/results/repair_dev.json, 1.6e-06, 2026 run"
    )
    assert history_marks(clean) == []


def test_a_record_without_its_parts_is_caught(tmp_path):
    bad = tmp_path / "0001-something.md"
    bad.write_text("# Something\n\n## Context\nwhy\n\n## Decision\nwhat\n")
    problems = record_problems(bad)
    assert any("'## Evidence'" in p for p in problems) and any("'## Date'" in p for p in problems)
    good = tmp_path / "0002-other.md"
    good.write_text(
        "# Other\n\n## Context\nwhy\n\n## Decision\nwhat\n\n## Evidence\n"
        "`benchmarks/results/repair_dev.json`\n\n## Date\n2026-11-24\n"
    )
    assert record_problems(good) == []
