"""The simulation engines the solver tests run on, and how a test asks for one.

A test of the solver runs on each of ``ENGINES`` (the ``mpm_engine`` fixture of conftest.py, or ``require`` plus
``using`` for cached runs shared between tests). The native engine's cases skip with the reason when its extension
is not built, and fail instead when ``VIRHEO_REQUIRE_NATIVE=1`` (CI).
"""
import contextlib
import os

import pytest

from mpm import runtime

ENGINES = ("taichi-cpu", "native")


def require(name: str) -> str:
    """``name``, after skipping (or, under VIRHEO_REQUIRE_NATIVE=1, failing) the test when it cannot run here."""
    if name == "native":
        why = runtime.native_missing()
        if why is not None:
            if os.environ.get("VIRHEO_REQUIRE_NATIVE") == "1":
                pytest.fail(f"VIRHEO_REQUIRE_NATIVE=1 but the native engine is not available: {why}")
            pytest.skip(f"native engine unavailable: {why}")
    return name


@contextlib.contextmanager
def using(name: str):
    """``VIRHEO_ARCH=name`` within the block (for runs cached across tests, outside monkeypatch's reach)."""
    old = os.environ.get("VIRHEO_ARCH")
    os.environ["VIRHEO_ARCH"] = name
    try:
        yield name
    finally:
        if old is None:
            os.environ.pop("VIRHEO_ARCH", None)
        else:
            os.environ["VIRHEO_ARCH"] = old
