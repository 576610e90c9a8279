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


def children(pid: int | None = None) -> set[int]:
    """Live (not zombie) descendants of ``pid`` (default: this process), from /proc."""
    pid = os.getpid() if pid is None else pid
    kids: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat", "rb") as fh:
                fields = fh.read().rsplit(b")", 1)[1].split()
        except OSError:
            continue
        if fields[0] == b"Z":
            continue
        try:
            with open(f"/proc/{d}/cmdline", "rb") as fh:
                if b"resource_tracker" in fh.read():  # multiprocessing's, ends with this process
                    continue
        except OSError:
            continue
        kids.setdefault(int(fields[1]), []).append(int(d))
    out, todo = set(), [pid]
    while todo:
        for c in kids.get(todo.pop(), []):
            if c not in out:
                out.add(c)
                todo.append(c)
    return out


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
