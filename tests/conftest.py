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
