"""Where batch items run: one small interface, three engines.

- :class:`InlineEngine`: in this process, one item at a time (``--engine local --jobs 1`` of
  the benches: exactly what ran before engines existed).
- :class:`LocalEngine`: worker processes on this machine, each with its own torch thread
  budget (``cpus // workers``) so that the workers do not oversubscribe the cores.
- :class:`RayEngine`: tasks on a Ray cluster (``--address auto|HOST:PORT|ray://HOST:PORT``),
  or on a local Ray started here; each task declares its CPUs (and a GPU for ``--device cuda``).

An engine runs ``fn(payload)`` for module-level functions ``fn`` (picklable by reference, so a
Ray worker imports the same facetex code a user's script runs). The worker catches the item's
own errors and sends them back as one line; an engine reports a worker that *died* (killed, out
of memory) separately (``Outcome.died``), so the caller can retry only those. ``cancel()`` stops
running items with an interrupt (their temporary files are removed by the ``finally`` clauses of
facetex's atomic writers), then kills what is left; ``close()`` reaps every process it started.

The process pool is hand-written: ``concurrent.futures`` fails *every* pending item when one
worker dies (BrokenProcessPool) and ``multiprocessing.Pool`` hangs; here a dead worker fails
only its item and is replaced.
"""

from __future__ import annotations

import itertools
import logging
import os
import signal
import socket
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable

from .._parallel import available_cpus
from ..errors import BadInputError, FacetexError

__all__ = ["Resources", "Outcome", "Engine", "InlineEngine", "LocalEngine", "RayEngine", "EngineError",
           "make_engine", "ENGINES", "execute", "ray_task_options", "MEMORY_MARGIN"]

ENGINES = ("local", "ray")
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


MEMORY_MARGIN = 1.25  # Ray requests: the measured peak of an item times this


def ray_task_options(resources: Resources, *, cpus_per_item: int = 1, gpus_per_item: float = 0.0,
                     observed_mb: float | None = None, node_memory_mb: float | None = None,
                     name: str = "item") -> dict:
    """The options of one item's Ray task (``remote_fn.options(**...)``).

    Parameters
    ----------
    resources : Resources
        What the item says it needs (its kind's measured peak memory, its CPUs and GPUs).
    cpus_per_item, gpus_per_item : int, float
        The engine's defaults where ``resources`` gives none.
    observed_mb : float, optional
        The largest peak resident memory (MB) measured so far for items of this function on
        this cluster: the request grows to :data:`MEMORY_MARGIN` times it when that is more.
    node_memory_mb : float, optional
        Ray's memory resource of the largest node: a request is capped there (Ray would wait
        forever for a node that large).
    name : str
        The task's name (shown in Ray's dashboard).

    Returns
    -------
    dict
        ``num_cpus``, ``num_gpus``, ``memory`` (bytes; absent when nothing is known),
        ``max_retries=0`` and ``retry_exceptions=False`` (the batch retries dead workers
        itself) and ``name``.
    """
    cpus = max(1, int(resources.cpus or cpus_per_item))
    opts: dict[str, Any] = {"num_cpus": cpus, "num_gpus": float(resources.gpus or gpus_per_item),
                            "max_retries": 0, "retry_exceptions": False, "name": f"facetex:{name}"}
    mb = max(float(resources.memory_mb or 0.0), MEMORY_MARGIN * float(observed_mb or 0.0))
    if node_memory_mb:
        mb = min(mb, float(node_memory_mb))
    if mb > 0:
        opts["memory"] = int(mb * 2**20)
    return opts


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


# ------------------------------------------------------------------------------------ Ray
def _fn_name(fn, payload) -> str:
    """The item function's name (a staged item's inner function: its memory is what counts)."""
    inner = payload.get("_staged_fn") if isinstance(payload, dict) else None
    return getattr(inner or fn, "__name__", "item")


def _ray_task(fn, payload, threads):
    """A Ray task: the same :func:`execute` the local workers run."""
    return execute(fn, payload, threads)


def _check_reachable(address: str) -> None:
    """A one-line error naming ``address`` when nothing listens there (Ray itself retries for a
    minute before it gives up)."""
    if address in ("auto", "local"):
        return
    hostport = address.split("://", 1)[-1].rstrip("/")
    host, _, port = hostport.rpartition(":")
    if not host or not port.isdigit():
        raise EngineError(f"--address {address}: give auto, HOST:PORT or ray://HOST:PORT")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=5.0):
            pass
    except OSError as e:
        raise EngineError(f"cannot reach the Ray cluster at {address}: {e.strerror or e} (is `ray start --head` "
                          "running there, and the port open?)") from None


class RayEngine(Engine):
    """Tasks on a Ray cluster. ``address``: "auto" (the cluster this machine belongs to),
    "HOST:PORT" (its GCS), "ray://HOST:PORT" (Ray client), or None: a local Ray started here
    with ``num_cpus`` CPUs (default the available CPUs) and stopped at ``close()``. A Ray
    already initialised in this process (``ray.init`` by the caller) is used as it is.
    ``jobs``: items in flight at once (default: the cluster's CPUs // ``cpus_per_item``).
    Each task asks for its item's CPUs, GPUs and memory (:func:`ray_task_options`: the kind's
    measured peak, raised to the largest peak measured in this run). ``runtime_env``: Ray's
    runtime environment of the job (``working_dir``, ``pip``, ``env_vars``), so that nodes need
    no manual install."""

    name = "ray"

    def __init__(self, address: str | None = None, *, jobs: int | None = None, cpus_per_item: int = 1,
                 gpus_per_item: float = 0.0, num_cpus: int | None = None, runtime_env: dict | None = None):
        self.address = address
        self.jobs = jobs
        self.cpus_per_item = max(1, int(cpus_per_item))
        self.gpus_per_item = float(gpus_per_item)
        self.num_cpus = num_cpus
        self.runtime_env = runtime_env
        self.slots = jobs or 1
        self._observed_mb: dict[str, float] = {}  # per item function: the largest peak RSS measured
        self._node_memory_mb: float | None = None
        self._owned = False
        self._refs: dict = {}  # ObjectRef -> (handle, submitted)
        self._ids = itertools.count()
        self._ray = None
        self._remote = None
        self._node_cpus: float | None = None

    def describe(self) -> dict:
        d = {"engine": self.name, "address": self.address or "local (started by facetex)", "slots": self.slots,
             "cpus_per_item": self.cpus_per_item, "gpus_per_item": self.gpus_per_item,
             "memory_request": f"the item kind's measured peak, or {MEMORY_MARGIN} x the largest measured in the run",
             "runtime_env": sorted(self.runtime_env) if self.runtime_env else None}
        if self._ray is not None and self._ray.is_initialized():
            try:
                res = self._ray.cluster_resources()
                d.update(cluster_cpus=res.get("CPU"), cluster_gpus=res.get("GPU", 0),
                         nodes=len([n for n in self._ray.nodes() if n.get("Alive")]))
            except Exception:  # noqa: BLE001 - description only
                pass
        return d

    def start(self) -> "RayEngine":
        try:
            import ray
        except ImportError:
            raise EngineError("--engine ray needs Ray: pip install 'facetex[ray]' (or pip install 'ray[client]')") \
                from None
        self._ray = ray
        if not ray.is_initialized():
            if self.address:
                _check_reachable(self.address)
            main = threading.current_thread() is threading.main_thread()
            saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)} if main else {}
            try:
                # Ray's start-up notices (token set-up, signal handlers) are not the user's concern
                kw: dict[str, Any] = {"logging_level": logging.ERROR, "log_to_driver": False}
                if self.runtime_env:
                    kw["runtime_env"] = self.runtime_env
                if self.address:
                    ray.init(address=self.address, **kw)
                else:
                    # "local": a new Ray here, even when a cluster runs on this machine ("auto" would join it)
                    ray.init(address="local", num_cpus=int(self.num_cpus or available_cpus()),
                             include_dashboard=False, **kw)
            except Exception as e:  # noqa: BLE001 - Ray raises many kinds; one line naming the address
                where = f"connect to Ray at {self.address}" if self.address else "start a local Ray"
                hint = ""
                if self.address and self.address != "auto" and os.environ.get("RAY_AUTH_MODE", "").lower() != "token":
                    hint = ("; if the cluster uses token authentication (Ray's default), set RAY_AUTH_MODE=token and "
                            "give its token (~/.ray/auth_token or RAY_AUTH_TOKEN)")
                raise EngineError(f"cannot {where}: {_one_line(str(e), 300)}{hint}") from None
            finally:
                for s, h in saved.items():  # ray.init installs its own SIGTERM handler (sys.exit)
                    signal.signal(s, h)
            self._owned = True
        cpus = float(ray.cluster_resources().get("CPU", 1.0))
        if self.gpus_per_item > 0 and float(ray.cluster_resources().get("GPU", 0.0)) < self.gpus_per_item:
            self.close()
            raise EngineError(f"the Ray cluster at {self.address or 'local'} has no GPU: use --device cpu")
        if cpus < self.cpus_per_item:
            self.close()
            raise EngineError(f"the Ray cluster has {cpus:g} CPUs, fewer than --cpus-per-item {self.cpus_per_item}")
        self.slots = int(self.jobs or max(1, int(cpus // self.cpus_per_item)))
        try:
            alive = [n.get("Resources", {}) for n in ray.nodes() if n.get("Alive")]
            self._node_cpus = max(float(r.get("CPU", 0.0)) for r in alive)
            self._node_memory_mb = max(float(r.get("memory", 0.0)) for r in alive) / 2**20 or None
        except (ValueError, Exception):  # noqa: BLE001 - unknown: let Ray decide
            self._node_cpus = self._node_memory_mb = None
        self._remote = ray.remote(_ray_task)
        return self

    def submit(self, fn, payload, resources=Resources()) -> int:
        if self._remote is None:
            self.start()
        fname = _fn_name(fn, payload)
        opts = ray_task_options(resources, cpus_per_item=self.cpus_per_item, gpus_per_item=self.gpus_per_item,
                                observed_mb=self._observed_mb.get(fname), node_memory_mb=self._node_memory_mb,
                                name=fname)
        cpus = opts["num_cpus"]
        if self._node_cpus is not None and cpus > self._node_cpus:  # Ray would wait for such a node forever
            raise EngineError(f"an item needs {cpus} CPUs but the largest node of the Ray cluster has "
                              f"{self._node_cpus:g}: ask for fewer (--cpus-per-item / --jobs)")
        h = next(self._ids)
        try:
            ref = self._remote.options(**opts).remote(fn, payload, cpus)
        except Exception as e:  # noqa: BLE001 - Ray client errors come in many kinds
            hint = " (is the same facetex installed on the cluster?)" if "ModuleNotFound" in str(e) else ""
            raise EngineError(f"the Ray cluster at {self.address or 'local'} did not take the task: "
                              f"{_one_line(str(e), 300)}{hint}") from None
        self._refs[ref] = (h, time.time(), fname)
        self.last_options = opts
        return h

    def pending(self) -> int:
        return len(self._refs)

    def wait(self, timeout=None) -> list[Outcome]:
        ray = self._ray
        if not self._refs:
            return []
        # Poll, sleeping in Python: a signal raised inside ray.wait reaches us as a bare KeyboardInterrupt
        # (Ray's C++ replaces the exception), so SIGTERM would look like Ctrl-C
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            ready, _ = ray.wait(list(self._refs), num_returns=len(self._refs), timeout=0)
            if ready or (deadline is not None and time.monotonic() >= deadline):
                break
            time.sleep(0.02)
        out = []
        for ref in ready:
            h, submitted, fname = self._refs.pop(ref)
            try:
                o = _outcome(h, ray.get(ref), submitted)
                peak = o.stats.get("peak_rss_mb")
                if isinstance(peak, (int, float)) and peak == peak:  # the next items of this kind ask for as much
                    self._observed_mb[fname] = max(self._observed_mb.get(fname, 0.0), float(peak))
                out.append(o)
            except ray.exceptions.TaskCancelledError:
                out.append(Outcome(h, False, error="cancelled", error_type="Cancelled",
                                   stats={"submitted": submitted, "returned": time.time()}))
            except ray.exceptions.RayTaskError as e:  # raised in the task outside the item (e.g. an import)
                cause = getattr(e, "cause", None) or e
                text = f"{type(cause).__name__}: {cause}" if cause is not e else str(e).strip().splitlines()[-1]
                hint = " (is the same facetex installed on every node?)" if isinstance(cause, ImportError) else ""
                out.append(Outcome(h, False, error=_one_line(text, 300) + hint, error_type=type(cause).__name__,
                                   stats={"submitted": submitted, "returned": time.time()}))
            except ray.exceptions.RayError as e:  # worker crashed, killed, out of memory, node lost
                first = _one_line(str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__, 300)
                out.append(Outcome(h, False, error=f"the Ray worker died ({type(e).__name__}: {first})",
                                   error_type=type(e).__name__, died=True,
                                   stats={"submitted": submitted, "returned": time.time()}))
        return out

    def cancel(self) -> None:
        ray = self._ray
        if ray is None or not self._refs:
            return
        refs = list(self._refs)
        for ref in refs:  # KeyboardInterrupt in the task: its atomic writers remove their temporary files
            try:
                ray.cancel(ref, force=False)
            except Exception:  # noqa: BLE001 - already finished
                pass
        _, left = ray.wait(refs, num_returns=len(refs), timeout=_CANCEL_GRACE_S)
        # force only the tasks still running: force-cancelling a task whose reply is already on
        # its way can abort the driver inside Ray (task_manager.cc "unexpected system state")
        for ref in left:
            try:
                ray.cancel(ref, force=True)
            except Exception:  # noqa: BLE001
                pass
        if left:
            ray.wait(left, num_returns=len(left), timeout=5.0)
        self._refs.clear()

    def close(self) -> None:
        ray = self._ray
        if ray is not None and self._owned and ray.is_initialized():
            ray.shutdown()
        self._owned = False
        self._refs.clear()


def make_engine(name: str = "local", *, jobs: int | None = None, address: str | None = None,
                cpus_per_item: int | None = None, device: str = "cpu", inline_single: bool = False,
                runtime_env: dict | None = None) -> Engine:
    """The engine of ``--engine NAME``. ``local``: ``jobs`` workers (default the available
    CPUs), ``cpus_per_item`` threads each (default ``cpus // jobs``); with ``inline_single`` and
    one job, items run in this process (the benches' old sequential behaviour). ``ray``: see
    :class:`RayEngine`; an item asks for one GPU when ``device`` is CUDA."""
    if name == "local":
        if address:
            raise BadInputError("--address is for --engine ray")
        if runtime_env:
            raise BadInputError("--runtime-env is for --engine ray")
        if inline_single and (jobs or available_cpus()) == 1 and jobs is not None:
            return InlineEngine()
        return LocalEngine(jobs, threads=cpus_per_item)
    if name == "ray":
        return RayEngine(address, jobs=jobs, cpus_per_item=cpus_per_item or 1,
                         gpus_per_item=1.0 if str(device).startswith("cuda") else 0.0, runtime_env=runtime_env)
    raise BadInputError(f"unknown engine {name!r}: use one of {', '.join(ENGINES)}")
