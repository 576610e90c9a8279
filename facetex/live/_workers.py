"""Child Python processes that run one worker object each, for the live stages that would otherwise
share this process's GIL (dlib's landmark fit, the rendering: two threads of one process ran only
1.03-1.13x faster than one, measured per stage).

A plain ``python -P -m facetex.live._workers`` subprocess, as :mod:`facetex.puppet._tracking` (not
multiprocessing: it does not re-import the caller's ``__main__``, and unlike ``fork`` it is safe after
OpenCV's threads ran; ``-P``: not the working folder first on the path). Protocol, pickle over the
child's stdin/stdout: ``("init", "module:factory", args)`` (the child answers ``("ok", None)`` once the
object is made), then ``("call", method, args)`` answered by ``("ok", result)`` or ``("error",
exception)``, and ``("cast", method, args)`` with no answer. Library output in the child goes to stderr."""

from __future__ import annotations

import importlib
import os
import pickle
import subprocess
import sys
import threading
import weakref
from pathlib import Path

from ..errors import FacetexError

__all__ = ["ChildWorker", "prestart", "worker", "discard_prestarted"]

_MODULE = "facetex.live._workers"


def _stop(proc) -> None:
    if proc.poll() is None:
        try:
            proc.stdin.close()
        except OSError:
            pass
        try:
            proc.wait(timeout=2)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    for s in (proc.stdout, proc.stdin):
        try:
            s.close()
        except OSError:
            pass


class ChildWorker:
    """The object ``factory(*args)`` (``"module:function"``) made and used in a child process.

    Raises OSError when no child can be started (the caller then works in this process)."""

    def __init__(self, factory: str, *args, name: str = "live worker"):
        self.name = name
        root = str(Path(__file__).resolve().parents[2])  # the folder holding this facetex package
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([root] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
        env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
        self._proc = subprocess.Popen([sys.executable, "-P", "-m", _MODULE], stdin=subprocess.PIPE,
                                      stdout=subprocess.PIPE, env=env)
        weakref.finalize(self, _stop, self._proc)
        self._lock = threading.Lock()
        self._ready = False
        self._send(("init", factory, args))

    def _send(self, msg) -> None:
        try:
            pickle.dump(msg, self._proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            self._proc.stdin.flush()
        except (OSError, ValueError):
            raise FacetexError(f"the {self.name} process stopped (exit code {self._proc.poll()})") from None

    def _receive(self):
        try:
            kind, value = pickle.load(self._proc.stdout)
        except (EOFError, OSError, pickle.UnpicklingError, ValueError):
            raise FacetexError(f"the {self.name} process stopped (exit code {self._proc.poll()})") from None
        if kind == "error":
            raise value
        return value

    def wait_ready(self) -> None:
        """Wait until the child has made its object (loaded its models)."""
        if self._ready:
            return
        with self._lock:
            if not self._ready:
                self._receive()
                self._ready = True

    def call(self, method: str, *args):
        """``method(*args)`` of the child's object; its result (its exception re-raised here)."""
        self.wait_ready()
        with self._lock:
            self._send(("call", method, args))
            return self._receive()

    def cast(self, method: str, *args) -> None:
        """``method(*args)`` of the child's object, without waiting for it (nor for the child's start:
        the child reads its messages in order)."""
        with self._lock:
            self._send(("cast", method, args))

    def close(self) -> None:
        _stop(self._proc)


#: workers started ahead by :func:`prestart`, by (factory, pickled args)
_PRESTARTED: dict = {}
_PRESTART_LOCK = threading.Lock()


def prestart(factory: str, *args, name: str = "live worker") -> None:
    """Start a worker now (the CLI, before its own imports: the child's start-up, ~1.5 s of model
    loading, then overlaps them); :func:`worker` with the same factory and arguments takes it."""
    key = (factory, pickle.dumps(args))
    with _PRESTART_LOCK:
        if key not in _PRESTARTED:
            try:
                _PRESTARTED[key] = ChildWorker(factory, *args, name=name)
            except OSError:
                pass


def worker(factory: str, *args, name: str = "live worker") -> ChildWorker:
    """A prestarted worker of ``factory(*args)``, or a new one (OSError: none can be started)."""
    with _PRESTART_LOCK:
        w = _PRESTARTED.pop((factory, pickle.dumps(args)), None)
    return w if w is not None else ChildWorker(factory, *args, name=name)


def discard_prestarted() -> None:
    """Stop the prestarted workers no session took (a command that failed before its session)."""
    with _PRESTART_LOCK:
        workers = list(_PRESTARTED.values())
        _PRESTARTED.clear()
    for w in workers:
        w.close()


def _child_main() -> int:
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # stray library prints must not corrupt the message stream
    sys.stdout = sys.stderr
    inp = sys.stdin.buffer
    import cv2

    cv2.setNumThreads(1)
    obj = pending = None
    while True:
        try:
            kind, *rest = pickle.load(inp)
        except (EOFError, OSError):
            return 0
        except KeyboardInterrupt:
            return 130
        try:
            if kind == "init":
                mod, fn = rest[0].split(":")
                obj = getattr(importlib.import_module(mod), fn)(*rest[1])
                msg = ("ok", None)
            elif kind == "cast":  # no answer: an error is kept for the next call's answer
                try:
                    getattr(obj, rest[0])(*rest[1])
                except Exception as e:  # noqa: BLE001
                    pending = e
                continue
            elif pending is not None:
                e, pending = pending, None
                raise e
            else:
                msg = ("ok", getattr(obj, rest[0])(*rest[1]))
        except KeyboardInterrupt:
            return 130
        except BaseException as e:  # noqa: BLE001 - everything goes back to the caller
            try:
                pickle.loads(pickle.dumps(e))
            except Exception:  # noqa: BLE001
                e = FacetexError(f"live worker failed: {type(e).__name__}: {e}")
            msg = ("error", e)
        try:
            pickle.dump(msg, out, protocol=pickle.HIGHEST_PROTOCOL)
            out.flush()
        except (BrokenPipeError, OSError):
            return 1


if __name__ == "__main__":
    sys.exit(_child_main())
