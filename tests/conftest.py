"""Shared test fixtures. ``../shared/data`` (beside the checkout) holds the dev/real/sample/lpips_ref data."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from go_pipeline.openmp import set_default_wait

set_default_wait(os.environ)  # before torch loads libgomp (see go_pipeline/openmp.py)

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.fail(f"{SHARED_DATA} is missing: CI and developers have ../shared beside the checkout")
    return SHARED_DATA


@pytest.fixture(scope="module")
def single_thread():
    """Opt in per module with ``pytestmark = pytest.mark.usefixtures("single_thread")``."""
    from tests._threads import one_thread

    with one_thread():
        yield
