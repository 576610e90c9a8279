"""The live tracker in a child Python process (:class:`ProcessTracker`), beside the puppet's work in
the caller: dlib's landmark fit holds the GIL, and the rest of a frame's work (numpy, OpenCV, the
texture blend's sparse products) holds it most of the time too, so two threads of one process ran
only 1.03-1.13x faster than one (measured per stage). A child process has its own interpreter: it
tracks frame t+1 while the caller renders frame t.

A plain ``python -P -m facetex.live._tracking`` subprocess, as :mod:`facetex.puppet._tracking`
(not multiprocessing: it does not re-import the caller's ``__main__``, and unlike ``fork`` it is safe
after OpenCV's threads ran). Protocol (pickle over pipes): the parent sends ``("params", DriverParams)``
once (the child answers ``("ok", None)`` when its models are loaded), then per frame ``("track", frame)``
or ``("lose", None)``; the child answers a ``track`` with ``("ok", (points68, mesh, score, why,
detections))`` or ``("error", exception)``."""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import threading
import weakref
from pathlib import Path

from ..errors import FacetexError

_MODULE = "facetex.live._tracking"


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


class ProcessTracker:
    """:class:`facetex.live.motion.CausalTracker` in a child process: the same calls and results.
    Falls back to tracking in this process when no child can be started."""

    def __init__(self, params):
        from .motion import CausalTracker

        self.params = params
        self.detections = 0  # counted by the child; not reported back (see stats' "detections": local only)
        self._lock = threading.Lock()
        self._local = None
        root = str(Path(__file__).resolve().parents[2])  # the folder holding this facetex package
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([root] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
        env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
        try:
            self._proc = subprocess.Popen([sys.executable, "-P", "-m", _MODULE], stdin=subprocess.PIPE,
                                          stdout=subprocess.PIPE, env=env)
        except OSError:
            self._proc = None
            self._local = CausalTracker(params)
            return
        weakref.finalize(self, _stop, self._proc)
        self._ready = False
        self._send(("params", params))

    def wait_ready(self) -> None:
        """Wait until the child has loaded its models (it answers the ``params`` message when it has)."""
        if self._local is not None or self._ready:
            return
        with self._lock:
            self._receive()
            self._ready = True

    def _receive(self):
        try:
            kind, value = pickle.load(self._proc.stdout)
        except (EOFError, OSError, pickle.UnpicklingError):
            raise FacetexError(f"the live tracking process stopped (exit code {self._proc.poll()})") from None
        if kind == "error":
            raise value
        return value

    def _send(self, msg) -> None:
        try:
            pickle.dump(msg, self._proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            self._proc.stdin.flush()
        except (OSError, ValueError):
            raise FacetexError(f"the live tracking process stopped (exit code {self._proc.poll()})") from None

    def __call__(self, frame) -> tuple:
        if self._local is not None:
            r = self._local(frame)
            self.detections = self._local.detections
            return r
        self.wait_ready()
        with self._lock:
            self._send(("track", frame))
            *r, self.detections = self._receive()
        return tuple(r)

    def lose(self) -> None:
        if self._local is not None:
            self._local.lose()
            return
        with self._lock:
            self._send(("lose", None))

    def close(self) -> None:
        if self._proc is not None:
            _stop(self._proc)


def _child_main() -> int:
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # stray library prints must not corrupt the message stream
    sys.stdout = sys.stderr
    inp = sys.stdin.buffer
    import cv2

    cv2.setNumThreads(1)
    from .motion import CausalTracker

    tracker = None
    while True:
        try:
            kind, value = pickle.load(inp)
        except (EOFError, OSError):
            return 0
        except KeyboardInterrupt:
            return 130
        try:
            if kind == "params":
                from .motion import load_tracking_models

                tracker = CausalTracker(value)
                load_tracking_models()
                msg = ("ok", None)
            elif kind == "lose":
                tracker.lose()
                continue
            else:
                msg = ("ok", tracker(value) + (tracker.detections,))
        except KeyboardInterrupt:
            return 130
        except BaseException as e:  # noqa: BLE001 - everything goes back to the caller
            try:
                pickle.loads(pickle.dumps(e))
            except Exception:  # noqa: BLE001
                e = FacetexError(f"live tracking failed: {type(e).__name__}: {e}")
            msg = ("error", e)
        try:
            pickle.dump(msg, out, protocol=pickle.HIGHEST_PROTOCOL)
            out.flush()
        except (BrokenPipeError, OSError):
            return 1


if __name__ == "__main__":
    sys.exit(_child_main())
