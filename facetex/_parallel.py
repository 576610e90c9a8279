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


def serialize_ast_parse() -> None:
    """Make :func:`ast.parse` take a process-wide lock (once; idempotent). CPython 3.11's
    conversion of a parsed tree to Python objects keeps its recursion depth in state shared by
    all threads (CPython gh-106905), so two threads parsing at once can fail with "SystemError:
    AST constructor recursion depth mismatch". numpy parses every ``.npy`` header with
    ``ast.literal_eval`` and :mod:`inspect` parses signatures: ``facetex puppet`` loads the
    persona on a thread while the main one imports and checks, and failed that way about once
    in a few dozen runs. A workaround, written by hand: no library changes the interpreter's
    ``ast`` module."""
    import ast
    import functools
    import threading

    if getattr(ast.parse, "_facetex_serialized", False):
        return
    lock = threading.RLock()
    parse = ast.parse

    @functools.wraps(parse)
    def locked_parse(*args, **kwargs):
        with lock:
            return parse(*args, **kwargs)

    locked_parse._facetex_serialized = True
    ast.parse = locked_parse
