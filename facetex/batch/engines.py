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

from .._parallel import available_cpus
from ..errors import BadInputError
from ._engine import Engine, EngineError, InlineEngine, Outcome, Resources, execute
from ._local_engine import LocalEngine
from ._ray_engine import MEMORY_MARGIN, RayEngine, ray_task_options

__all__ = [  # in the order of the reference page
    "ENGINES", "EngineError", "Resources", "MEMORY_MARGIN", "ray_task_options", "Outcome", "execute",
    "Engine", "InlineEngine", "LocalEngine", "RayEngine", "make_engine",
]

ENGINES = ("local", "ray")


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
