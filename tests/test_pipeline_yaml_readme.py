"""The `--set` spellings of the README (the paper's ablations) and of docs/ablations.md (every other switch)
must stay valid params of pipeline.yaml."""

from __future__ import annotations

import re
from pathlib import Path

from go_pipeline.pipeline import load_pipeline, parse_set_argument

README = Path(__file__).resolve().parents[1] / "README.md"
ABLATIONS = Path(__file__).resolve().parents[1] / "docs" / "ablations.md"


def spellings_of(path: Path) -> list[str]:
    return re.findall(r"`--set ([a-z_]+\.[a-z_]+=[^`]+)`", path.read_text())


def test_every_set_spelling_in_the_readme_and_the_ablations_page_is_a_valid_override():
    assert len(spellings_of(README)) >= 10  # the paper's ablation table
    assert len(spellings_of(ABLATIONS)) >= 30  # every other switch
    spellings = spellings_of(README) + spellings_of(ABLATIONS)
    pipeline = load_pipeline()
    for text in spellings:
        dotted, value = parse_set_argument(text)
        resolved = pipeline.resolve_params(overrides={dotted: value})
        step, param = dotted.split(".")
        assert resolved[step][param] == value, text
