"""Helpers of the batch tests that test modules import (not from ``conftest``: every test
folder has one, and which module that name means depends on the order pytest loads them)."""

from __future__ import annotations

import os
from pathlib import Path

HERE = Path(__file__).resolve().parent


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
