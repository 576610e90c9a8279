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


#: a value of :func:`patched_items` that removes the key for the while
REMOVE = object()


@contextlib.contextmanager
def patched_items(mapping, changes: dict):
    """``mapping`` (a dict, ``os.environ``, a module's ``__dict__``) with ``changes`` applied for
    the ``with`` block (a value :data:`REMOVE` deletes its key), then every key as it was."""
    missing = object()
    saved = {k: mapping.get(k, missing) for k in changes}
    for k, v in changes.items():
        if v is REMOVE:
            mapping.pop(k, None)
        else:
            mapping[k] = v
    try:
        yield mapping
    finally:
        for k, v in saved.items():
            if v is missing:
                mapping.pop(k, None)
            else:
                mapping[k] = v


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
    with patched_items(main.__dict__, {"__file__": REMOVE, "__spec__": None}):
        yield


#: bytes of an AF_UNIX socket path (sun_path holds 108 with the closing NUL)
_SOCKET_PATH_MAX = 107
#: where multiprocessing's folder goes when TMPDIR is too long a path (the first writable one)
_SHORT_TEMP_FOLDERS = ("/tmp", "/var/tmp", "/dev/shm")


def short_socket_folder() -> None:
    """Make multiprocessing's temporary folder (``pymp-*``, where the forkserver listens on an
    AF_UNIX socket ``listener-*``) somewhere its socket path fits: under a long ``TMPDIR`` the
    pool failed with "OSError: AF_UNIX path too long". The folder is then made in the first
    writable one of /tmp, /var/tmp, /dev/shm (and removed at exit, as multiprocessing does);
    when none fits, one error line (a shorter TMPDIR or one job)."""
    import multiprocessing.util
    import tempfile

    from .errors import UsageError

    socket_len = lambda folder: len(os.fsencode(folder)) + len("/listener-12345678")  # noqa: E731
    if socket_len(tempfile.gettempdir()) + len("/pymp-12345678") <= _SOCKET_PATH_MAX:
        return  # (made there on first use)
    short = next((d for d in _SHORT_TEMP_FOLDERS if os.path.isdir(d) and os.access(d, os.W_OK | os.X_OK)), None)
    saved = tempfile.tempdir
    try:
        tempfile.tempdir = short or saved
        folder = multiprocessing.util.get_temp_dir()  # made once per process, then reused
    finally:
        tempfile.tempdir = saved
    if socket_len(folder) > _SOCKET_PATH_MAX:
        raise UsageError(f"the temporary folder {folder} is too long a path for the worker processes' socket "
                         f"({len(os.fsencode(folder))} bytes; at most {_SOCKET_PATH_MAX - 18}): set a shorter "
                         "TMPDIR, or use --jobs 1")


def die_with(pid: int, sig: int | None = None) -> None:
    """Send this (worker) process ``sig`` (default SIGTERM: the work unwinds, temporary files go)
    as soon as process ``pid``, the one that started it, has ended, also by SIGKILL, which no
    cleanup code of its sees: its workers would otherwise run their task to the end (and write
    its output) and wait for more. When ``pid`` is the parent, Linux's parent-death signal
    (``prctl(PR_SET_PDEATHSIG)``) does it. A forkserver's workers are the forkserver's children,
    and it lives as long as they do, so for them a daemon thread waits on a pidfd of ``pid``
    (readable once it has exited; Linux >= 5.3), else polls it."""
    import signal
    import threading

    sig = int(signal.SIGTERM if sig is None else sig)
    if pid == os.getppid():
        try:
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(1, sig)  # PR_SET_PDEATHSIG
            if os.getppid() != pid:  # it died before the prctl
                os.kill(os.getpid(), sig)
            return
        except (OSError, AttributeError):  # not Linux: watch it as below
            pass
    try:
        fd = os.pidfd_open(pid)
    except (AttributeError, OSError):  # another OS, an old kernel, or pid already gone
        fd = None

    def watch():
        if fd is not None:
            import select

            select.select([fd], [], [])
        else:
            import time

            while True:
                time.sleep(0.5)
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    break
                except PermissionError:  # alive (another user's process with our pid: reused)
                    pass
        os.kill(os.getpid(), sig)

    threading.Thread(target=watch, name="facetex-parent-watch", daemon=True).start()
