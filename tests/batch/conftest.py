"""Shared fixtures of the batch tests: the worker-side task module on the workers' path, and a
check that no process a test started (local workers, Ray) outlives it."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _procs import children  # noqa: E402 - a module of its own: every test folder has a "conftest"


@pytest.fixture
def no_leftover_processes():
    """Fails the test when a child process it started is still alive at its end."""
    before = children()
    yield
    deadline = time.monotonic() + 15
    while (left := children() - before) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not left, f"processes left behind: {sorted(left)}"


@pytest.fixture
def worker_path(monkeypatch):
    """Local spawn workers get sys.path from this process; Ray workers need PYTHONPATH."""
    parts = [str(HERE), str(HERE.parents[1])] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(dict.fromkeys(parts)))
