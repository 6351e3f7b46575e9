"""The README's `--set` spellings (ablations) must stay valid params of pipeline.yaml."""

from __future__ import annotations

import re
from pathlib import Path

from go_pipeline.pipeline import load_pipeline, parse_set_argument

README = Path(__file__).resolve().parents[1] / "README.md"


def test_every_set_spelling_in_the_readme_is_a_valid_override():
    spellings = re.findall(r"`--set ([a-z_]+\.[a-z_]+=[^`]+)`", README.read_text())
    assert len(spellings) >= 10  # the ablation table
    pipeline = load_pipeline()
    for text in spellings:
        dotted, value = parse_set_argument(text)
        resolved = pipeline.resolve_params(overrides={dotted: value})
        step, param = dotted.split(".")
        assert resolved[step][param] == value, text
