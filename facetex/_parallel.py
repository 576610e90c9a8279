"""The thread budget shared by facetex's own thread pools."""

from __future__ import annotations

import os


def available_cpus() -> int:
    """Threads to use: ``OMP_NUM_THREADS`` when set (the budget BLAS also follows, so a
    one-core benchmark stays on one core), else the CPUs this process may run on."""
    env = os.environ.get("OMP_NUM_THREADS", "").strip()
    if env.isdigit() and int(env) > 0:
        return int(env)
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def terminate_workers(executor) -> None:
    """Stop the worker processes of a concurrent.futures ProcessPoolExecutor now (SIGTERM),
    instead of letting them finish their current task; ``shutdown(wait=True)`` then reaps
    them. Used when the parent is interrupted: nothing of theirs is wanted any more."""
    for p in list((getattr(executor, "_processes", None) or {}).values()):  # private, but stable since 3.8
        try:
            p.terminate()
        except (OSError, ValueError, AttributeError):
            pass
