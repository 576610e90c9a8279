"""Driver tracking in a child Python process, beside the puppet's setup in the caller.

dlib's model loading (~1.2 s) and its landmark fits hold the GIL, so on a thread they stall
the persona loading and texture precomputation that run beside them. A child process has its
own interpreter. It is a plain ``python -m facetex.puppet._tracking`` subprocess (not
multiprocessing): it does not re-import the caller's ``__main__``, and unlike ``fork`` it is
safe after OpenCV's thread pool has run (a forked child hangs in OpenCV's parallel code).

Protocol (pickle over pipes): the parent writes ``{"path", "size_of", "kwargs"}`` of
:func:`~facetex.puppet.driver.track_driver` to the child's stdin; the child writes
``("progress", lost)`` per frame, then ``("done", DriverTrack)`` or ``("error", exception)``
to its stdout (library output in the child goes to stderr)."""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import threading
import weakref
from pathlib import Path
from typing import Callable

from ..errors import FacetexError

_MODULE = "facetex.puppet._tracking"


class DriverTracking:
    """:func:`~facetex.puppet.driver.track_driver` of one video, started now and collected by
    :meth:`result`. ``process``: in a child process (the default), else on the caller's thread
    when :meth:`result` is called (also the fallback when no child process can be started).

    ``size_of``: a .persona path whose canonical frame replaces ``params.size`` (``params``
    None: the default DriverParams); it is read in the child, so a caller can start the
    tracking before it has imported numpy."""

    def __init__(self, path, *, process: bool = True, size_of=None, **kwargs):
        self.path, self._kwargs, self._size_of = path, kwargs, size_of
        self._proc = None
        if process:
            try:
                self._proc = _start_child(path, size_of, kwargs)
            except OSError:  # no usable interpreter for a child (embedded Python): track in-thread
                self._proc = None
            else:  # a tracking dropped unread must not leave its child blocked on a full pipe
                weakref.finalize(self, _stop, self._proc)

    @property
    def kwargs(self) -> dict:
        """The keyword arguments of track_driver (the persona's size resolved)."""
        return _resolved(self._size_of, self._kwargs)

    def result(self, progress: Callable | None = None):
        """The DriverTrack (errors of the tracking re-raised here, e.g. NoFaceError naming the video)."""
        from .driver import track_driver

        if self._proc is None:
            return track_driver(self.path, progress=progress, **self.kwargs)
        proc, self._proc = self._proc, None
        try:
            while True:
                try:
                    kind, value = pickle.load(proc.stdout)
                except EOFError:
                    code = proc.wait()
                    raise FacetexError(f"the driver tracking process stopped (exit code {code}) before it finished",
                                       path=self.path) from None
                if kind == "progress":
                    if progress:
                        progress(n=1, stage="track", lost=value)
                elif kind == "error":
                    raise value
                else:
                    return value
        finally:
            _stop(proc)

    def cancel(self) -> None:
        """Stop the child process (if any); :meth:`result` must not be called after."""
        if self._proc is not None:
            _stop(self._proc)
            self._proc = None


def _stop(proc) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.wait()
    if not proc.stdout.closed:
        proc.stdout.close()


def _resolved(size_of, kwargs) -> dict:
    """track_driver's keyword arguments: ``params=None`` is the default DriverParams, and with
    ``size_of`` its size is that persona's canonical frame."""
    if size_of is None and kwargs.get("params", True) is not None:
        return kwargs
    from dataclasses import replace

    from ..persona.collection import read_persona_header
    from .driver import DriverParams

    params = kwargs.get("params") or DriverParams()
    if size_of is not None:
        params = replace(params, size=tuple(read_persona_header(size_of)["size"]))
    return dict(kwargs, params=params)


def _start_child(path, size_of, kwargs) -> subprocess.Popen:
    root = str(Path(__file__).resolve().parents[2])  # the folder holding this facetex package
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([root] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    # one core's work (the caller's setup has the other): no idle BLAS/OpenMP threads
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    # -P: not the working folder first on the path (-m puts it there), where another checkout's
    # facetex would be imported instead of this one
    proc = subprocess.Popen([sys.executable, "-P", "-m", _MODULE], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            env=env)
    job = pickle.dumps({"path": path, "size_of": size_of, "kwargs": kwargs}, protocol=pickle.HIGHEST_PROTOCOL)
    # written from a thread: a child that dies at start must not block the caller on a full pipe
    threading.Thread(target=_feed, args=(proc.stdin, job), daemon=True).start()
    return proc


def _feed(stream, data: bytes) -> None:
    try:
        stream.write(data)
        stream.close()
    except OSError:  # the child died: result() reports it
        pass


def _picklable(exc: BaseException) -> BaseException:
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:
        return FacetexError(f"driver tracking failed: {type(exc).__name__}: {exc}")


def _child_main() -> int:
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # stray library prints must not corrupt the message stream
    sys.stdout = sys.stderr
    job = pickle.load(sys.stdin.buffer)

    def send(msg) -> None:
        pickle.dump(msg, out, protocol=pickle.HIGHEST_PROTOCOL)
        out.flush()

    try:
        import cv2

        cv2.setNumThreads(1)
        from .driver import track_driver

        track = track_driver(job["path"], progress=lambda n=1, lost=0, **_: send(("progress", lost)),
                             **_resolved(job["size_of"], job["kwargs"]))
        send(("done", track))
    except (KeyboardInterrupt, BrokenPipeError):  # Ctrl-C reaches the whole process group; the parent reports
        return 130
    except BaseException as e:  # noqa: BLE001 - everything goes back to the caller
        try:
            send(("error", _picklable(e)))
        except BrokenPipeError:
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(_child_main())
