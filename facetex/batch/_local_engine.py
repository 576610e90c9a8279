"""The local engine: a hand-written pool of worker processes on this machine, in which a dead
worker fails only its item and is replaced."""

from __future__ import annotations

import itertools
import os
import signal
import socket
import time
from collections import deque

from .._parallel import available_cpus
from ._engine import (
    _CANCEL_GRACE_S,
    _THREAD_ENV,
    Engine,
    Outcome,
    Resources,
    _one_line,
    _outcome,
    execute,
)


# ----------------------------------------------------------------------------- local pool
def _interrupt(signum, frame):
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise KeyboardInterrupt(signal.Signals(signum).name)


def _worker_main(conn, parent_pid: int) -> None:
    """A local worker: run (handle, fn, payload, threads) messages until None or EOF."""
    from .._parallel import die_with

    die_with(parent_pid)  # SIGTERM when the batch dies, even by SIGKILL: no worker outlives it
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the terminal's Ctrl-C is the batch's to handle
    signal.signal(signal.SIGTERM, _interrupt)  # cancel: unwind, so temporary files are removed
    try:
        while True:
            msg = conn.recv()
            if msg is None:
                return
            handle, fn, payload, threads = msg
            result = execute(fn, payload, threads)
            try:
                conn.send((handle, result))
            except (TypeError, AttributeError, ValueError) as e:  # the result does not pickle
                conn.send((handle, (False, _one_line(f"result could not be sent back: {e}"), type(e).__name__,
                                    result[3])))
    except (KeyboardInterrupt, EOFError, OSError, BrokenPipeError):
        return


class _Worker:
    def __init__(self, ctx, env: dict):
        from .._parallel import main_script_hidden, patched_items

        parent, child = ctx.Pipe()
        self.spawned = time.time()  # the batch's timings: start-up and idle time of each worker
        self.process = ctx.Process(target=_worker_main, args=(child, os.getpid()), name="facetex-batch-worker")
        # a spawned interpreter starts with this environment (BLAS reads it once), and without
        # re-running a user's plain script
        with patched_items(os.environ, env), main_script_hidden():
            self.process.start()
        child.close()
        self.conn = parent
        self.task: tuple | None = None  # (handle, submitted time)

    @property
    def pid(self) -> int:
        return self.process.pid

    def stop(self, timeout: float) -> None:
        p = self.process
        if p.is_alive() and self.task is None:
            try:
                self.conn.send(None)
            except OSError:  # already told, or gone
                pass
        p.join(timeout)
        if p.is_alive():
            p.terminate()
            p.join(_CANCEL_GRACE_S)
        if p.is_alive():
            p.kill()
            p.join()
        self.conn.close()


def _death_message(exitcode: int | None) -> str:
    if exitcode is not None and exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        why = " (out of memory?)" if -exitcode == signal.SIGKILL else ""
        return f"the worker process was killed by {name}{why}"
    return f"the worker process exited with code {exitcode}"


class LocalEngine(Engine):
    """``jobs`` worker processes on this machine (default: the available CPUs), each running
    items with ``threads`` torch/BLAS threads (default ``cpus // jobs``, at least 1). Workers
    are fresh interpreters (spawn), started on first use and replaced when one dies."""

    name = "local"

    def __init__(self, jobs: int | None = None, *, threads: int | None = None):
        cpus = available_cpus()
        self.jobs = max(1, int(jobs or cpus))
        self.threads = max(1, int(threads or cpus // self.jobs or 1))
        self.slots = self.jobs
        self._workers: list[_Worker | None] = [None] * self.jobs
        self._queue: deque = deque()
        self._ids = itertools.count()
        self._where: dict[int, int] = {}  # handle -> worker slot
        self._ctx = None

    def describe(self) -> dict:
        return {"engine": self.name, "workers": self.jobs, "threads_per_worker": self.threads,
                "host": socket.gethostname()}

    def start(self) -> "LocalEngine":
        import multiprocessing

        self._ctx = multiprocessing.get_context("spawn")
        return self

    def _env(self) -> dict:
        # OpenMP threads that wait sleep instead of spinning, as the command line sets it (see
        # facetex.cli._passive_openmp; the user's own choice is kept): with 2 threads per item on
        # a shared 2-core machine the spinning threads took 8.7 instead of 1.1 CPU s per item's
        # optimisation (load 3-4; same bytes)
        return {**{k: str(self.threads) for k in _THREAD_ENV},
                "OMP_WAIT_POLICY": os.environ.get("OMP_WAIT_POLICY", "PASSIVE")}

    def submit(self, fn, payload, resources=Resources()) -> int:
        if self._ctx is None:
            self.start()
        h = next(self._ids)
        self._queue.append((h, fn, payload, max(1, int(resources.cpus or self.threads)), time.time()))
        self._dispatch()
        return h

    def pending(self) -> int:
        return len(self._queue) + sum(1 for w in self._workers if w is not None and w.task is not None)

    def worker_pid(self, handle: int) -> int | None:
        k = self._where.get(handle)
        w = self._workers[k] if k is not None else None
        return w.pid if w is not None and w.task is not None and w.task[0] == handle else None

    def _dispatch(self) -> None:
        for k in range(self.jobs):
            if not self._queue:
                return
            w = self._workers[k]
            if w is not None and w.task is not None:
                continue
            if w is None or not w.process.is_alive():
                if w is not None:
                    w.stop(0)
                w = self._workers[k] = _Worker(self._ctx, self._env())
            h, fn, payload, threads, submitted = self._queue.popleft()
            try:
                w.conn.send((h, fn, payload, min(threads, self.threads)))
            except (OSError, BrokenPipeError):  # died between the check and the send: try it again
                self._queue.appendleft((h, fn, payload, threads, submitted))
                w.stop(0)
                self._workers[k] = None
                continue
            w.task = (h, submitted)
            self._where[h] = k

    def wait(self, timeout=None) -> list[Outcome]:
        from multiprocessing.connection import wait as mp_wait

        busy = [w for w in self._workers if w is not None and w.task is not None]
        if not busy:
            return []
        ready = set(mp_wait([w.conn for w in busy] + [w.process.sentinel for w in busy], timeout))
        out = []
        for k, w in enumerate(self._workers):
            if w is None or w.task is None or not (w.conn in ready or w.process.sentinel in ready):
                continue
            h, submitted = w.task
            msg = None
            try:
                if w.conn.poll():
                    msg = w.conn.recv()
            except (EOFError, OSError):
                msg = None
            w.task = None
            self._where.pop(h, None)
            if msg is not None:
                out.append(_outcome(h, msg[1], submitted))
                out[-1].stats["worker_spawned"] = w.spawned
                continue
            w.process.join(5)
            code = w.process.exitcode
            out.append(Outcome(h, False, error=_death_message(code), error_type="WorkerDied", died=True,
                               stats={"pid": w.pid, "host": socket.gethostname(), "submitted": submitted,
                                      "returned": time.time(), "exitcode": code}))
            w.stop(0)
            self._workers[k] = None
        self._dispatch()
        return out

    def cancel(self) -> None:
        """SIGTERM the busy workers (the item unwinds: temporary files removed), wait for them,
        then kill what is left; queued items are dropped."""
        self._queue.clear()
        busy = [w for w in self._workers if w is not None and w.task is not None]
        for w in busy:
            try:
                w.process.terminate()
            except (OSError, ValueError):
                pass
        deadline = time.monotonic() + _CANCEL_GRACE_S
        for w in busy:
            w.process.join(max(0.0, deadline - time.monotonic()))
            if w.process.is_alive():
                w.process.kill()
                w.process.join()
            w.task = None

    def close(self) -> None:
        live = [w for w in self._workers if w is not None]
        for w in live:  # all at once: the interpreters wind down in parallel
            if w.process.is_alive() and w.task is None:
                try:
                    w.conn.send(None)
                except OSError:
                    pass
        deadline = time.monotonic() + 5.0
        for w in live:
            w.task = None
            w.stop(max(0.0, deadline - time.monotonic()))
        self._workers = [None] * self.jobs
        self._where.clear()
