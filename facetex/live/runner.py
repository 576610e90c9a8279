"""The streaming runner: a source's frames through a :class:`~facetex.live.LiveSession` to a window,
a file and/or a callback, with stale frames dropped and the stages pipelined.

Threads (numpy, OpenCV, the mesh network and PyAV release the GIL in most of their work):

* the **reader** takes frames from the source as they arrive (a file at its own frame rate) into a
  one-frame mailbox (:class:`~facetex.live.sources.LatestFrame`): a frame not taken before the next
  arrives is dropped, so the processing always takes the newest frame;
* the **tracker** runs :meth:`LiveSession.prepare` (tracking, motion, mesh, texture) of frame t+1
  while
* the **renderer** (the calling thread) runs :meth:`LiveSession.finish` (render, composite) of frame
  t and hands the output to the sinks;
* the **writer** encodes the output file (H.264 through :func:`facetex.io.write_video`: a temporary
  file renamed at the end, nothing written when no puppet frame came out). A frame dropped before
  processing is filled in the file by repeating the previous output, so the file keeps the source's
  timing.

The end report (:func:`run_live`) has the session's :meth:`~LiveSession.stats`: fps, dropped
frames, latency percentiles from arrival to output, time to the first puppet frame."""

from __future__ import annotations

import os
import queue
import sys
import threading
import time
from typing import Callable

import numpy as np

from ..errors import BadInputError
from .sources import LatestFrame, open_source, source_kind

__all__ = ["run_live", "display_available"]

_END = object()

#: libx264's options for the live recording: its default preset (medium, 40 frames of look-ahead)
#: competed with the stream for the CPU (docs/live.md)
LIVE_ENCODER = {"preset": "veryfast", "tune": "zerolatency"}


def display_available() -> bool:
    """Whether an OpenCV window can be shown here (a display, and OpenCV built with a GUI)."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return False
    import cv2

    try:
        return "NONE" not in cv2.getBuildInformation().split("GUI:")[1].split("\n")[0].upper()
    except (IndexError, cv2.error):
        return False


class _Writer:
    """The output file, written on its own thread from the first output frame on."""

    def __init__(self, path, fps: float, overwrite: bool, inputs):
        self.path, self.fps, self.overwrite, self.inputs = path, fps, overwrite, inputs
        self.q: queue.Queue = queue.Queue(maxsize=16)
        self.thread = None
        self.error: BaseException | None = None
        self.last_index = -1
        self.last = None
        self.frames = 0

    def _frames(self):
        while True:
            f = self.q.get()
            if f is _END:
                return
            if isinstance(f, BaseException):
                raise f
            yield f

    def _run(self):
        from ..io import write_video

        try:
            write_video(self.path, self._frames(), self.fps, overwrite=self.overwrite, inputs=self.inputs,
                        encoder_options=LIVE_ENCODER)
        except BaseException as e:  # noqa: BLE001 - re-raised by the runner
            self.error = e
            while True:  # unblock the producer
                try:
                    self.q.get_nowait()
                except queue.Empty:
                    break

    def put(self, index: int, frame: np.ndarray) -> None:
        if self.error is not None:
            raise self.error
        if self.thread is None:
            self.thread = threading.Thread(target=self._run, name="facetex-live-writer", daemon=True)
            self.thread.start()
        else:  # frames dropped before processing: the previous output again, keeping the timing
            for _ in range(index - self.last_index - 1):
                self._q(self.last)
        self._q(frame)
        self.last, self.last_index = frame, index

    def _q(self, item) -> None:
        self.frames += item is not _END and not isinstance(item, BaseException)
        while self.thread.is_alive():
            try:
                self.q.put(item, timeout=0.5)
                return
            except queue.Full:
                continue
        if self.error is not None:
            raise self.error

    def close(self, error: BaseException | None = None):
        """Finish the file (or, with ``error``, abandon it: nothing is written); the path or None."""
        if self.thread is None:
            return None
        try:
            self._q(error if error is not None else _END)
        except BaseException:  # noqa: BLE001 - the writer already failed
            pass
        self.thread.join()
        if error is None and self.error is not None:
            raise self.error
        return None if error is not None else self.path


def run_live(source, persona=None, *, session=None, size: int | None = 256, mode: str = "composite",
             output=None, overwrite: bool = False, window: bool = False, on_frame: Callable | None = None,
             max_frames: int | None = None, duration: float | None = None, loop: int = 1, realtime: bool = True,
             params=None, live=None, progress: Callable | None = None, pipeline: bool = True,
             wait: bool | None = None) -> dict:
    """Run a live puppet over a source until it ends (or ``max_frames`` frames came in, or ``duration``
    seconds passed, or the window's Esc/q).

    Parameters
    ----------
    source : int, str or os.PathLike
        A camera index, ``/dev/videoN``, a URL or a video file (:func:`facetex.live.open_source`).
    persona : str, os.PathLike or Persona, optional
        The puppet (or give a ``session``).
    session : LiveSession, optional
        A session to run (its size, mode and settings); default a new one of ``persona``.
    size, mode, params, live
        As :class:`LiveSession`.
    output : str or os.PathLike, optional
        An H.264 video file of the output frames at the source's frame rate.
    overwrite : bool
        Replace an existing ``output``.
    window : bool
        Show the output in an OpenCV window (BadInputError when there is no display).
    on_frame : callable, optional
        Called with each output record of :meth:`LiveSession.finish` (on the rendering thread; keep it short).
    max_frames, duration : optional
        Stop after this many source frames, or seconds.
    loop : int
        A file source is played this many times.
    realtime : bool
        A file source is played at its frame rate (default), or as fast as it decodes.
    progress : callable, optional
        Called about once a second with the current :meth:`LiveSession.stats`.
    pipeline : bool
        Track on a second thread while rendering (default); False: both on this thread.
    wait : bool, optional
        Start reading the source once the persona is loaded (default for a file: its first frames then
        make the reference instead of being dropped while the persona loads); a camera or URL starts at
        once (frames seen while the persona loads make the reference).

    Returns
    -------
    dict
        The session's :meth:`~LiveSession.stats` with "source", "fps_source", "output" (the file or None).

    Raises
    ------
    facetex.NoFaceError
        No puppet frame came out (no usable face in the stream): no file is written.
    facetex.BadInputError
        A bad source (missing or unreadable file, camera not available), no display for ``window``.
    """
    from .session import LiveSession

    if window and not display_available():
        raise BadInputError("no display to show a window (DISPLAY is not set, or OpenCV has no GUI): give -o OUT.mp4")
    out_path = None
    if output is not None:
        from ..io import VIDEO_EXTENSIONS, check_output_path

        out_path = check_output_path(output, overwrite=overwrite, extensions=VIDEO_EXTENSIONS, what="video",
                                     inputs=[p for p in (source, persona) if isinstance(p, (str, os.PathLike))
                                             and os.path.exists(p)])
    own = session is None
    if own:
        if persona is None:
            raise BadInputError("give a persona or a LiveSession")
        session = LiveSession(persona, size=size, mode=mode, params=params, live=live)
    try:
        return _run(session, source, out_path, overwrite=overwrite, window=window, on_frame=on_frame,
                    max_frames=max_frames, duration=duration, loop=loop, realtime=realtime, progress=progress,
                    pipeline=pipeline, wait=wait)
    finally:
        if own:
            session.close()


def _run(session, source, out_path, *, overwrite, window, on_frame, max_frames, duration, loop, realtime, progress,
         pipeline, wait) -> dict:
    src = open_source(source, realtime=realtime, loop=loop)
    if wait is None:
        wait = source_kind(source) == "file"
    if wait:  # a file starts playing when the puppet can follow it (its first frames make the reference)
        try:
            session.wait_loaded()
        except BaseException:
            src.close()
            raise
    writer = _Writer(out_path, src.fps, overwrite, []) if out_path is not None else None
    stats = session.stats_
    mailbox, handoff = LatestFrame(), queue.Queue(maxsize=1)
    errors: list = []
    stop = threading.Event()
    t_start = time.perf_counter()

    def read():
        n = 0
        try:
            for frame, t in src.frames():
                if stop.is_set() or (duration is not None and time.perf_counter() - t_start >= duration):
                    break
                stats.arrived()
                if mailbox.put((frame, time.perf_counter(), t, n)):
                    stats.drop()
                n += 1
                if max_frames is not None and n >= max_frames:
                    break
        except BaseException as e:  # noqa: BLE001
            errors.append(e)
        finally:
            mailbox.close()

    def track():
        try:
            while not stop.is_set():
                item = mailbox.get()
                if item is None:
                    break
                frame, arrival, t, index = item
                work = session.prepare(frame, arrival=arrival, t=t, fps=src.fps, index=index)
                while not stop.is_set():
                    try:
                        handoff.put(work, timeout=0.2)
                        break
                    except queue.Full:
                        continue
        except BaseException as e:  # noqa: BLE001
            errors.append(e)
        finally:
            while True:  # the end mark, unless the renderer stopped taking (then it is not waiting)
                try:
                    handoff.put(_END, timeout=0.2)
                    break
                except queue.Full:
                    if stop.is_set():
                        break

    def next_work():
        if pipeline:
            return handoff.get()
        item = mailbox.get()
        if item is None:
            return _END
        frame, arrival, t, index = item
        return session.prepare(frame, arrival=arrival, t=t, fps=src.fps, index=index)

    reader = threading.Thread(target=read, name="facetex-live-reader", daemon=True)
    tracker = threading.Thread(target=track, name="facetex-live-tracker", daemon=True) if pipeline else None
    error = None
    shown = False
    next_report = time.perf_counter() + 1.0
    try:
        reader.start()
        if tracker is not None:
            tracker.start()
        while True:
            work = next_work()
            if work is _END:
                break
            rec = session.finish(work)
            if rec["output"] is not None:
                if writer is not None:
                    writer.put(rec["index"], rec["output"])
                if window:
                    import cv2

                    cv2.imshow("facetex live", cv2.cvtColor(rec["output"], cv2.COLOR_RGB2BGR))
                    shown = True
                    if cv2.waitKey(1) & 0xFF in (27, ord("q")):
                        break
            if on_frame is not None:
                on_frame(rec)
            if progress is not None and time.perf_counter() >= next_report:
                next_report += 1.0
                progress(session.stats())
        if errors:
            raise errors[0]
        session.require_face(src.name)
    except BaseException as e:
        error = e
        raise
    finally:
        stop.set()
        src.close()
        mailbox.close()
        while True:  # unblock the tracker
            try:
                handoff.get_nowait()
            except queue.Empty:
                break
        reader.join(timeout=5)
        if tracker is not None:
            tracker.join(timeout=5)
        written = writer.close(error) if writer is not None else None
        if shown:
            import cv2

            cv2.destroyAllWindows()
    report = session.stats()
    report.update(source=src.name, fps_source=src.fps, output=None if written is None else str(written),
                  wall_s=round(time.perf_counter() - t_start, 3))
    return report
