"""Shared test fixtures. ``../shared/data`` (beside the checkout) holds the dev/real/sample/lpips_ref data."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from go_pipeline.openmp import set_default_wait

set_default_wait(os.environ)  # before torch loads libgomp (see go_pipeline/openmp.py)
# the toy pipelines of the runner tests name their own step modules: the explicit opt-in to custom steps
# (tests/test_trust.py checks the default, without it)
os.environ["GO_ALLOW_CUSTOM_STEPS"] = "1"

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The larger data beside the checkout (``../shared/data``); tests needing it skip without it (a fresh
    clone), saying so: CI and developers have it."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"needs the shared data set at {SHARED_DATA} (not part of a fresh clone)")
    return SHARED_DATA


@pytest.fixture(scope="module")
def single_thread():
    """Opt in per module with ``pytestmark = pytest.mark.usefixtures("single_thread")``."""
    from tests._threads import one_thread

    with one_thread():
        yield


# The optional stacks (pyproject extras): a test that needs one skips, saying which extra, where it is not
# installed (a base `pip install -e .`); `pip install -e ".[dev]"` pulls them, so CI runs those tests.
EXTRA_OF_MODULE = {"diffusers": "sd15", "transformers": "sd15", "peft": "sd15", "ray": "ray"}


def _missing_extra(excinfo) -> str | None:
    if excinfo is None or not isinstance(excinfo[1], ModuleNotFoundError):
        return None
    extra = EXTRA_OF_MODULE.get((excinfo[1].name or "").split(".")[0])
    return f"needs the [{extra}] extra: pip install -e '.[{extra}]'" if extra else None


def _skip_when_an_extra_is_missing():
    outcome = yield
    why = _missing_extra(outcome.excinfo)
    if why:
        outcome.force_exception(pytest.skip.Exception(why, _use_item_location=True))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_setup(item):
    yield from _skip_when_an_extra_is_missing()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item):
    yield from _skip_when_an_extra_is_missing()
