"""One-line error reports from library exceptions (go_core.errors.first_line)."""

from __future__ import annotations

import pytest

from go_core.diffusion import models
from go_core.errors import MissingWeightsError, first_line


@pytest.mark.parametrize(
    ("exc", "expected"),
    [
        (ValueError("bad value\ndetails"), "bad value"),
        (ValueError("\n   \n  second line  \nthird"), "second line"),
        (OSError(), "OSError"),
        (KeyError(""), "''"),  # KeyError's str() is the repr of its key
        (RuntimeError(""), "RuntimeError"),
    ],
)
def test_first_line(exc, expected):
    assert first_line(exc) == expected


def test_load_error_with_empty_message_still_reported(monkeypatch, tmp_path):
    """A library error without a message becomes a MissingWeightsError naming the exception type."""
    monkeypatch.setattr(models, "require_weights", lambda paths, need_controlnet=True: None)

    def boom(paths, dtype):
        raise OSError()

    monkeypatch.setattr(models, "_load_sd_components", boom)
    paths = models.WeightPaths(sd15=str(tmp_path / "sd15"), controlnet=str(tmp_path / "cn"))
    with pytest.raises(MissingWeightsError, match=r"could not load the repair model from .*: OSError$"):
        models.load_repair_models(paths)
