import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import engines  # noqa: E402
from mpm.datasets import data_dir  # noqa: E402


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The shared data folder; skipped when absent, a failure when VIRHEO_REQUIRE_DATA=1 (CI)."""
    d = data_dir()
    if d is None:
        if os.environ.get("VIRHEO_REQUIRE_DATA") == "1":
            pytest.fail("VIRHEO_REQUIRE_DATA=1 but ../shared/data (or $VIRHEO_DATA) is missing")
        pytest.skip("shared data absent: set VIRHEO_DATA or put it at ../shared/data")
    return d


@pytest.fixture(params=engines.ENGINES)
def mpm_engine(request, monkeypatch) -> str:
    """Each simulation engine in turn (tests/engines.py), set as $VIRHEO_ARCH for the test."""
    monkeypatch.setenv("VIRHEO_ARCH", engines.require(request.param))
    return request.param
