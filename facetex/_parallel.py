"""The thread budget shared by facetex's own thread pools."""

from __future__ import annotations

import contextlib
import os
import sys


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


@contextlib.contextmanager
def main_script_hidden():
    """While worker processes start, the parent's ``__main__`` is not re-run in them.

    multiprocessing's spawn and forkserver start methods import the parent's main script (or
    ``-m`` module) in every child as ``__mp_main__``: a plain script calling
    :func:`facetex.build_persona` without ``if __name__ == "__main__":`` ran itself again in
    each worker, which then failed ("a worker process died"). facetex's workers run module
    functions and need nothing from ``__main__``, so its ``__file__`` and ``__spec__`` are
    hidden from :func:`multiprocessing.spawn.get_preparation_data` while processes start."""
    main = sys.modules.get("__main__")
    if main is None:
        yield
        return
    missing = object()
    saved = {a: main.__dict__.get(a, missing) for a in ("__file__", "__spec__")}
    main.__dict__.pop("__file__", None)
    main.__dict__["__spec__"] = None
    try:
        yield
    finally:
        for a, v in saved.items():
            if v is missing:
                main.__dict__.pop(a, None)
            else:
                main.__dict__[a] = v
