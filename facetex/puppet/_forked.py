"""A forked child process whose results the parent takes as futures: the puppet's second pass
renders part of its frames there.

Why a process: a frame's mesh and composite are many small numpy and OpenCV calls that hold the
GIL. Two render threads ran no faster than one (75 frames of a 256 px clip, mesh and composite:
1.07 s on one thread, 1.41 s on two); a child forked after the setup shares the persona's texture
stacks copy-on-write, so it starts at once (~10 ms) and the second core renders beside the first
(the same 75 frames: 1.84 s -> 1.05 s split between the two, every frame the same bits; whole
frames differ by < 1e-5, their textures being blended in other batches).

Linux only (``fork``; other systems keep the threads), and only from the main thread of a process
that may have children: a fork copies no other thread, and a lock another thread held at that moment
(inside OpenCV, say, in a server rendering two clips at once) would stay held in the child.
"""

from __future__ import annotations

import os
import pickle
import sys
import threading
import warnings
from concurrent.futures import Future
from typing import Callable, Iterable, Iterator

__all__ = ["fork_available", "ForkedResults"]


def fork_available() -> bool:
    """Whether a child can be forked safely here: Linux, the main thread, not a daemonic process."""
    import multiprocessing as mp

    return (sys.platform.startswith("linux") and "fork" in mp.get_all_start_methods()
            and threading.current_thread() is threading.main_thread() and not mp.current_process().daemon)


def _portable_error(e: BaseException) -> BaseException:
    """What the parent can rebuild of ``e``: a facetex error as (class, message, file) (its pickle
    would lose the file), another error itself if it survives pickling, else a RuntimeError with
    its text."""
    from ..errors import FacetexError

    if isinstance(e, FacetexError):
        parts = (type(e), e.message, e.path)
        try:
            pickle.dumps(parts)  # a class defined where the parent cannot import it
        except Exception:  # noqa: BLE001 - any failure: the plain text instead
            return RuntimeError(str(e))
        return parts
    try:
        return pickle.loads(pickle.dumps(e))
    except Exception:  # noqa: BLE001
        return RuntimeError(f"{type(e).__name__}: {e}")


def _child_main(produce: Callable[[Callable], Iterator], conn, inbox, parents_end, credit, parent: int) -> None:
    from .._parallel import die_with

    die_with(parent)  # a parent killed outright (SIGKILL) leaves no child waiting for credit
    parents_end.close()  # the parent's end of the inbox: the child sees its end when the parent closes it
    try:
        gen = produce(inbox.recv)
        while True:
            try:
                key, value = next(gen)
            except StopIteration as stop:
                conn.send(("end", None, stop.value))
                break
            if credit is not None:  # at most ``ahead`` values not yet taken by the parent
                credit.acquire()
            conn.send(("item", key, value))
    except BaseException as e:  # noqa: BLE001 - handed to the parent, which raises it
        err = _portable_error(e)
        conn.send(("error", None, err))
    finally:
        conn.close()


class ForkedResults:
    """Run the generator function ``produce(receive)`` (yielding (key, value), returning a final
    value) in a forked child; ``receive()`` there returns the next object the parent :meth:`send`s
    (EOFError once the parent has closed). :meth:`future` is the future of the value of ``key``
    (one of ``keys``), :meth:`result` the final value. ``ahead``: the child waits while this many
    values are sent and not yet :meth:`taken` (a long video's frames do not pile up when the parent
    is the slower; a taken value is let go). A child's error, or its death, fails every pending future with that error.
    :meth:`close` stops the child (when it has not ended) and reaps it."""

    def __init__(self, produce: Callable[[Callable], Iterator], keys: Iterable, *, ahead: int | None = None):
        import multiprocessing as mp
        import queue

        ctx = mp.get_context("fork")
        self._credit = None if ahead is None else ctx.Semaphore(max(1, int(ahead)))
        self._futures = {k: Future() for k in keys}
        self._end: Future = Future()
        for f in (*self._futures.values(), self._end):
            f.set_running_or_notify_cancel()
        recv, send = ctx.Pipe(duplex=False)
        inbox, outbox = ctx.Pipe(duplex=False)
        for stream in (sys.stdout, sys.stderr):  # else the child flushes a copy of what is buffered
            try:
                stream.flush()
            except (AttributeError, OSError, ValueError):
                pass
        with warnings.catch_warnings():  # Python 3.12+ warns of forking a threaded process (see above)
            warnings.simplefilter("ignore", DeprecationWarning)
            self._proc = ctx.Process(target=_child_main, args=(produce, send, inbox, outbox, self._credit, os.getpid()),
                                     daemon=True, name="facetex-puppet-render")
            self._proc.start()
        send.close()
        inbox.close()
        self._conn = recv
        self._reader = threading.Thread(target=self._read, name="facetex-puppet-render-reader", daemon=True)
        self._reader.start()
        # the parent's objects go out on a thread: a full pipe (the child busy) never blocks the caller
        self._outbox, self._queue = outbox, queue.SimpleQueue()
        self._sender = threading.Thread(target=self._send_all, name="facetex-puppet-render-sender", daemon=True)
        self._sender.start()

    def _send_all(self) -> None:
        try:
            while (obj := self._queue.get()) is not _CLOSE:
                self._outbox.send(obj)
        except (OSError, ValueError):  # the child has ended: its futures say why
            pass
        finally:
            self._outbox.close()

    def send(self, obj) -> None:
        """Hand ``obj`` to the child's ``receive()`` (in order; never blocks)."""
        self._queue.put(obj)

    def done_sending(self) -> None:
        """No more :meth:`send`: the child's ``receive()`` raises EOFError after the last object."""
        self._queue.put(_CLOSE)

    def _read(self) -> None:
        err: BaseException | None = None
        try:
            while True:
                kind, key, value = self._conn.recv()
                if kind == "item":
                    f = self._futures.get(key)
                    if f is not None:  # else let go before it came
                        f.set_result(value)
                elif kind == "end":
                    self._end.set_result(value)
                    return
                else:
                    err = value
                    break
        except (EOFError, OSError):
            self._proc.join(timeout=1.0)  # for its exit code
            err = RuntimeError(f"the render process {self._proc.pid} ended unexpectedly "
                               f"(exit code {self._proc.exitcode}): re-run the command")
        except BaseException as e:  # noqa: BLE001 - an unreadable message
            err = e
        if isinstance(err, tuple):  # a facetex error: (class, message, path)
            cls, message, path = err
            err = cls(message, path=path)
        for f in (*list(self._futures.values()), self._end):
            if not f.done():
                f.set_exception(err)

    def future(self, key) -> Future:
        return self._futures[key]

    def taken(self, key) -> None:
        """The value of ``key`` has been used: it is let go here (a long video's frames are not
        all kept), and the child may send one more (with ``ahead``)."""
        self._futures.pop(key, None)
        if self._credit is not None:
            self._credit.release()

    def result(self):
        """The final value ``produce`` returned (waits for the child's end)."""
        return self._end.result()

    def close(self) -> None:
        if self._proc.is_alive() and not self._end.done():
            self._proc.terminate()
        self._proc.join()
        self._queue.put(_CLOSE)
        self._sender.join()
        self._reader.join()
        self._conn.close()


_CLOSE = object()  # the sender thread's stop
