"""The Ray engine: items as tasks on a Ray cluster (or a local Ray started here), with what each
task asks Ray for."""

from __future__ import annotations

import itertools
import logging
import os
import signal
import socket
import threading
import time
from typing import Any

from .._parallel import available_cpus
from ._engine import (
    _CANCEL_GRACE_S,
    Engine,
    EngineError,
    Outcome,
    Resources,
    _one_line,
    _outcome,
    execute,
)

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


# ------------------------------------------------------------------------------------ Ray
def _fn_name(fn, payload) -> str:
    """The item function's name (a staged item's inner function: its memory is what counts)."""
    inner = payload.get("_staged_fn") if isinstance(payload, dict) else None
    return getattr(inner or fn, "__name__", "item")


_WATCHED: set = set()


def _ray_task(fn, payload, threads, driver_pid=None):
    """A Ray task: the same :func:`execute` the local workers run. ``driver_pid`` (a local Ray
    started by facetex): the task's worker gets SIGTERM when that process ends, also by SIGKILL
    (:func:`facetex._parallel.die_with`), instead of finishing the item and writing its output
    while the manifest says running (issue 23)."""
    if driver_pid is not None and driver_pid not in _WATCHED:
        from .._parallel import die_with

        _WATCHED.add(driver_pid)
        die_with(int(driver_pid))
    return execute(fn, payload, threads)


def _process_start(pid: int) -> str | None:
    """Start time of a live (not zombie) process of this host, or None."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            stat = fh.read()
    except OSError:
        return None
    fields = stat[stat.rindex(b")") + 2:].split()
    return None if fields[0] == b"Z" else fields[19].decode()


def _descendants(pid: int) -> dict[int, str]:
    """{pid: start time} of the live descendants of ``pid`` (Linux /proc; empty elsewhere)."""
    parents: dict[int, list[int]] = {}
    try:
        entries = os.listdir("/proc")
    except OSError:
        return {}
    for name in entries:
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat", "rb") as fh:
                stat = fh.read()
        except OSError:
            continue
        parents.setdefault(int(stat[stat.rindex(b")") + 2:].split()[1]), []).append(int(name))
    out: dict[int, str] = {}
    todo = list(parents.get(pid, ()))
    while todo:
        q = todo.pop()
        st = _process_start(q)
        if st is not None:
            out[q] = st
        todo.extend(parents.get(q, ()))
    return out


#: The watchdog of a local Ray started by facetex: a process of its own reading "PID:START" lines
#: (the Ray processes: GCS, raylet, agents, workers) from a pipe whose other end only this
#: process holds. "exit" ends it quietly (Ray was shut down); end of file means this process
#: ended without shutting Ray down (SIGKILL): it sends the recorded processes still alive SIGTERM
#: (the task's atomic writers remove their temporary files), then SIGKILL after 3 s.
_REAPER = r"""
import os, signal, sys, time
for s in (signal.SIGINT, signal.SIGHUP, signal.SIGTERM):
    signal.signal(s, signal.SIG_IGN)
def start(pid):
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            stat = fh.read()
    except OSError:
        return None
    f = stat[stat.rindex(b")") + 2:].split()
    return None if f[0] == b"Z" else f[19].decode()
known = {}
for line in sys.stdin:
    if line.strip() == "exit":
        sys.exit(0)
    for tok in line.split():
        pid, _, st = tok.partition(":")
        known[int(pid)] = st
left = lambda: [p for p, st in known.items() if start(p) == st]
for sig in (signal.SIGTERM, signal.SIGKILL):
    for p in left():
        try:
            os.kill(p, sig)
        except OSError:
            pass
    t = time.monotonic()
    while sig == signal.SIGTERM and left() and time.monotonic() - t < 3:
        time.sleep(0.1)
"""


class _RayReaper:
    """The watchdog process of a local Ray (see :data:`_REAPER`); :meth:`record` tells it the
    Ray processes (descendants of this one), at most every ``every`` seconds."""

    def __init__(self, every: float = 2.0):
        import subprocess
        import sys

        self.every, self._last, self._sent = every, 0.0, {}
        self.proc = subprocess.Popen([sys.executable, "-c", _REAPER], stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL, text=True, start_new_session=True)
        self.record(force=True)

    def record(self, force: bool = False) -> None:
        now = time.monotonic()
        if self.proc.stdin is None or (not force and now - self._last < self.every):
            return
        self._last = now
        new = {p: st for p, st in _descendants(os.getpid()).items() if p != self.proc.pid and self._sent.get(p) != st}
        if new:
            try:
                self.proc.stdin.write(" ".join(f"{p}:{st}" for p, st in new.items()) + "\n")
                self.proc.stdin.flush()
                self._sent.update(new)
            except (OSError, ValueError):
                pass

    def close(self) -> None:
        """Ray was shut down: the watchdog ends without killing anything."""
        try:
            if self.proc.stdin is not None:
                self.proc.stdin.write("exit\n")
                self.proc.stdin.close()
        except (OSError, ValueError):
            pass
        try:
            self.proc.wait(timeout=5)
        except Exception:  # noqa: BLE001
            self.proc.kill()
            self.proc.wait()


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
        self._reaper: _RayReaper | None = None

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
            if os.path.isdir("/proc"):  # Ray's processes end with this one, also when it is SIGKILLed
                try:
                    self._reaper = _RayReaper()
                except OSError:
                    self._reaper = None
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
            ref = self._remote.options(**opts).remote(fn, payload, cpus,
                                                      os.getpid() if self._reaper is not None else None)
        except Exception as e:  # noqa: BLE001 - Ray client errors come in many kinds
            hint = " (is the same facetex installed on the cluster?)" if "ModuleNotFound" in str(e) else ""
            raise EngineError(f"the Ray cluster at {self.address or 'local'} did not take the task: "
                              f"{_one_line(str(e), 300)}{hint}") from None
        self._refs[ref] = (h, time.time(), fname)
        self.last_options = opts
        if self._reaper is not None:
            self._reaper.record(force=True)
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
            if self._reaper is not None:  # workers Ray starts for the tasks
                self._reaper.record()
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
        if self._reaper is not None:
            self._reaper.close()
            self._reaper = None
        self._owned = False
        self._refs.clear()
