"""The engine interface and what every engine shares: an item's resources and outcome, running
one item in a worker (its thread budget, its peak memory, its error as one line), and the
in-process engine."""

from __future__ import annotations

import itertools
import os
import socket
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable

from ..errors import FacetexError

# the item's thread budget, for every pool a transfer uses: torch's OpenMP, BLAS, and OpenCV's own
# pthreads pool (which ignores OMP_NUM_THREADS and otherwise starts one thread per core in every worker)
_THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "OPENCV_FOR_THREADS_NUM")
_CANCEL_GRACE_S = 10.0  # an interrupted item gets this long to remove its temporary files


class EngineError(FacetexError):
    """An engine cannot start (Ray missing or unreachable)."""


@dataclass(frozen=True)
class Resources:
    """What one item needs: CPUs (also its torch thread budget), GPUs (Ray schedules it on a
    node that has them) and memory in MB (its measured peak; Ray puts no more items on a node
    than its memory holds; 0: no request)."""

    cpus: int = 1
    gpus: float = 0.0
    memory_mb: float = 0.0


@dataclass
class Outcome:
    """A finished item: ``ok`` with ``value`` (the function's result), or not ok with ``error``
    (one line) and ``died`` (the worker died: killed, out of memory; worth a retry)."""

    handle: int
    ok: bool
    value: Any = None
    error: str | None = None
    error_type: str | None = None
    died: bool = False
    stats: dict = field(default_factory=dict)  # host, pid, seconds (in the worker), peak_rss_mb, submitted


def _one_line(text: str, limit: int = 500) -> str:
    s = " ".join(str(text).split())
    return s if len(s) <= limit else s[: limit - 1] + "…"


def _set_threads(threads: int) -> None:
    """The item's thread budget: BLAS/OpenMP/OpenCV read the environment when they start
    (before torch or cv2 is imported), torch and OpenCV also take it later. OpenCV's thread
    count does not change its results (each thread computes whole rows), torch's does."""
    for k in _THREAD_ENV:
        os.environ[k] = str(threads)
    torch = sys.modules.get("torch")
    if torch is not None and torch.get_num_threads() != threads:
        torch.set_num_threads(threads)
    cv2 = sys.modules.get("cv2")
    if cv2 is not None and hasattr(cv2, "setNumThreads") and cv2.getNumThreads() != threads:
        cv2.setNumThreads(threads)


def _cpu_s() -> float:
    """CPU seconds (user + system) this process used so far, all its threads."""
    t = os.times()
    return t.user + t.system


def _peak_rss_mb() -> float:
    try:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux
    except (ImportError, OSError):  # pragma: no cover - not on Linux
        return float("nan")


def _call(fn: Callable, payload: Any) -> Any:
    """``fn(payload)``, its temporary files tagged with the batch run's tag (``payload["batch"]["tag"]``),
    so that the run can tell them from a user's files (see :func:`facetex.io.temp_tag`)."""
    from ..io import temp_tag

    batch = payload.get("batch") if isinstance(payload, dict) else None
    with temp_tag(batch.get("tag") if isinstance(batch, dict) else None):
        return fn(payload)


def execute(fn: Callable, payload: Any, threads: int) -> tuple:
    """Run one item in a worker: ``(ok, value or error line, error type, stats)``. Errors of the
    item become one line; KeyboardInterrupt (a cancel) propagates after the item's clean-up."""
    t0, c0, started = time.perf_counter(), _cpu_s(), time.time()
    _set_threads(threads)
    try:
        value, ok, etype = _call(fn, payload), True, None
    except FacetexError as e:
        value, ok, etype = _one_line(str(e)), False, type(e).__name__
    except MemoryError:
        value, ok, etype = "out of memory", False, "MemoryError"
    except Exception as e:  # noqa: BLE001 - any failure of an item is recorded, the batch goes on
        value, ok, etype = _one_line(f"{type(e).__name__}: {e}"), False, type(e).__name__
    if ok and ("torch" in sys.modules or "cv2" in sys.modules):
        _set_threads(threads)  # the item imported torch or cv2: keep the budget for the next item too
    stats = {"host": socket.gethostname(), "pid": os.getpid(), "seconds": time.perf_counter() - t0,
             "cpu_s": _cpu_s() - c0, "started": started, "peak_rss_mb": _peak_rss_mb(), "threads": int(threads)}
    return ok, value, etype, stats


def _outcome(handle: int, result: tuple, submitted: float) -> Outcome:
    ok, value, etype, stats = result
    stats = dict(stats, submitted=submitted, returned=time.time())
    if ok:
        return Outcome(handle, True, value=value, stats=stats)
    return Outcome(handle, False, error=value, error_type=etype, stats=stats)


class Engine:
    """The interface every engine has. ``slots``: how many items run at once."""

    name = "engine"
    slots = 1

    def start(self) -> "Engine":
        return self

    def submit(self, fn: Callable, payload: Any, resources: Resources = Resources()) -> int:
        raise NotImplementedError

    def wait(self, timeout: float | None = None) -> list[Outcome]:
        """Finished items (at least one, or none after ``timeout`` seconds)."""
        raise NotImplementedError

    def pending(self) -> int:
        raise NotImplementedError

    def worker_pid(self, handle: int) -> int | None:
        """The process running ``handle``, when the engine knows it."""
        return None

    def cancel(self) -> None:
        """Stop every running item now (interrupt, then kill after a grace period)."""

    def close(self) -> None:
        """Stop and reap every process this engine started."""

    def describe(self) -> dict:
        return {"engine": self.name, "slots": self.slots}

    def __enter__(self):
        return self.start()

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None:
            self.cancel()
        self.close()


class InlineEngine(Engine):
    """Items run in this process when waited for, one at a time (no isolation, no pickling)."""

    name = "inline"
    slots = 1

    def __init__(self, threads: int | None = None):
        self.threads = threads
        self._queue: deque = deque()
        self._ids = itertools.count()

    def submit(self, fn, payload, resources=Resources()) -> int:
        h = next(self._ids)
        self._queue.append((h, fn, payload, time.time()))
        return h

    def pending(self) -> int:
        return len(self._queue)

    def wait(self, timeout=None) -> list[Outcome]:
        if not self._queue:
            return []
        h, fn, payload, submitted = self._queue.popleft()
        if self.threads:
            return [_outcome(h, execute(fn, payload, self.threads), submitted)]
        t0 = time.perf_counter()
        value = _call(fn, payload)  # errors propagate, as before engines: the caller's own loop
        return [Outcome(h, True, value=value, stats={"host": socket.gethostname(), "pid": os.getpid(),
                                                       "seconds": time.perf_counter() - t0, "submitted": submitted,
                                                       "returned": time.time(), "peak_rss_mb": _peak_rss_mb()})]

    def cancel(self) -> None:
        self._queue.clear()
