"""Frame sources of a live stream and the one-frame mailbox that drops stale frames.

A source yields (uint8 RGB frame, its time in the stream in seconds):

* a video file, played at its own frame rate (``realtime``: each frame is handed over at its time,
  not as fast as it decodes; ``loop``: played that many times, for benchmarks);
* a camera: an index (``0``) or a V4L2 device (``/dev/video0``), read with OpenCV;
* a URL (``rtsp://``, ``http://``, ...), read with PyAV (FFmpeg) as the network delivers it.

:class:`LatestFrame` holds the newest frame only: a frame put while the previous one was not yet
taken replaces it, and the replaced one counts as dropped. The processing thus always takes the
newest frame and its latency stays one frame's processing, however slow it is."""

from __future__ import annotations

import os
import re
import threading
import time
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import BadInputError

__all__ = ["LatestFrame", "FrameSource", "PushSource", "open_source", "source_kind"]


class LatestFrame:
    """A one-item mailbox: :meth:`put` replaces an item not yet taken (returning True: it was dropped),
    :meth:`get` waits for an item and takes it; after :meth:`close` it gives None once empty."""

    def __init__(self):
        self._cond = threading.Condition()
        self._item = None
        self._closed = False

    def put(self, item) -> bool:
        with self._cond:
            dropped = self._item is not None
            self._item = item
            self._cond.notify()
            return dropped

    def get(self, timeout: float | None = None):
        """The newest item (None: closed and empty, or ``timeout`` seconds passed)."""
        with self._cond:
            if self._item is None and not self._closed:
                self._cond.wait_for(lambda: self._item is not None or self._closed, timeout)
            item, self._item = self._item, None
            return item

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()


def source_kind(source) -> str:
    """"camera", "url" or "file" of a ``--source`` value (an int or digits: a camera index)."""
    if isinstance(source, FrameSource):
        return "push"
    s = str(source)
    if isinstance(source, int) or s.isdigit() or re.fullmatch(r"/dev/video\d+", s):
        return "camera"
    if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*://", s) and not s.startswith("file://"):
        return "url"
    return "file"


class FrameSource:
    """An opened source: ``fps`` (nominal), ``size`` (W, H) or None until the first frame, ``name``;
    iterate :meth:`frames` once; :meth:`close` stops it (also from another thread)."""

    def __init__(self, name: str, fps: float, frames: Iterator, size=None, closer=None):
        self.name, self.fps, self.size = name, fps, size
        self._frames, self._closer = frames, closer
        self.stopped = threading.Event()

    def frames(self) -> Iterator[tuple[np.ndarray, float]]:
        for item in self._frames:
            if self.stopped.is_set():
                break
            yield item

    def close(self) -> None:
        self.stopped.set()
        if self._closer is not None:
            self._closer()


class PushSource(FrameSource):
    """A source whose frames the caller hands in (the studio's WebSocket handler): :meth:`push` each
    decoded uint8 RGB frame as it arrives, :meth:`close` at the end of the stream. Give it to
    :func:`facetex.live.run_live` as the source and take the outputs from its ``on_frame``: the runner
    drops stale frames and pipelines the stages as for a camera.

    Parameters
    ----------
    fps : float
        The stream's nominal frame rate (the output file's, when one is written).
    name : str
        What errors and the report call the stream.

    Examples
    --------
    >>> feed = PushSource(fps=25)                                        # doctest: +SKIP
    >>> threading.Thread(target=run_live, args=(feed,), kwargs=dict(session=s, on_frame=send)).start()  # doctest: +SKIP
    >>> feed.push(frame)   # per received frame; feed.close() when the socket closes  # doctest: +SKIP
    """

    _END = object()

    def __init__(self, fps: float = 25.0, name: str = "pushed frames"):
        import queue

        self._q: queue.Queue = queue.Queue()
        self._t0 = None
        super().__init__(name, float(fps), self._pull())

    def push(self, frame: np.ndarray, t: float | None = None) -> None:
        """Hand in one frame (``t``: its time in the stream in seconds; default the time since the first)."""
        now = time.perf_counter()
        if self._t0 is None:
            self._t0 = now
        self._q.put((frame, now - self._t0 if t is None else float(t)))

    def close(self) -> None:
        self._q.put(self._END)
        super().close()

    def _pull(self):
        while True:
            item = self._q.get()
            if item is self._END:
                return
            yield item


def _camera(source) -> FrameSource:
    import cv2

    s = str(source)
    dev = int(s) if s.isdigit() else s
    if isinstance(dev, str) and not os.path.exists(dev):
        raise BadInputError("camera not available: no such device", path=s)
    cap = cv2.VideoCapture(dev)
    if not cap.isOpened():
        cap.release()
        raise BadInputError(f"camera {s} is not available (no such camera, busy, or no permission)", path=None)
    ok, first = cap.read()
    if not ok or first is None:
        cap.release()
        raise BadInputError(f"camera {s} gives no frames (busy, or no permission)", path=None)
    fps = float(cap.get(cv2.CAP_PROP_FPS) or 0) or 25.0
    t0 = time.perf_counter()

    def frames():
        yield cv2.cvtColor(first, cv2.COLOR_BGR2RGB), 0.0
        while True:
            ok, f = cap.read()
            if not ok:
                return
            yield cv2.cvtColor(f, cv2.COLOR_BGR2RGB), time.perf_counter() - t0

    return FrameSource(f"camera {s}", fps, frames(), (first.shape[1], first.shape[0]), cap.release)


def _url(url: str) -> FrameSource:
    import av

    try:
        c = av.open(url, timeout=10.0)
    except (av.FFmpegError, OSError, ValueError) as e:
        raise BadInputError(f"cannot open the stream ({e})", path=url) from None
    if not c.streams.video:
        c.close()
        raise BadInputError("no video stream at this URL", path=url)
    s = c.streams.video[0]
    fps = float(s.average_rate or s.guessed_rate or 0) or 25.0
    t0 = time.perf_counter()

    def frames():
        try:
            for f in c.decode(s):
                yield f.to_ndarray(format="rgb24"), time.perf_counter() - t0
        except (av.FFmpegError, OSError) as e:
            raise BadInputError(f"the stream broke off ({e})", path=url) from None

    return FrameSource(url, fps, frames(), (s.codec_context.width, s.codec_context.height), c.close)


def _file(path, *, realtime: bool, loop: int) -> FrameSource:
    from ..io import iter_video_frames, video_info
    from ..puppet.driver import DRIVER_MAX_SIDE

    path = Path(path)
    info = video_info(path)  # a missing, unreadable or frameless file fails here, naming it
    fps = info["fps"] or 25.0
    src = FrameSource(str(path), fps, iter(()), (info["width"], info["height"]))

    def frames():
        n = 0
        t0 = time.perf_counter()
        for _ in range(max(1, int(loop))):
            for f in iter_video_frames(path, uint8=True, max_side=DRIVER_MAX_SIDE):
                t = n / fps
                if realtime:  # handed over at its time in the stream, as a camera would
                    wait = t0 + t - time.perf_counter()
                    if wait > 0 and src.stopped.wait(wait):
                        return
                yield f, t
                n += 1

    src._frames = frames()
    return src


def open_source(source, *, realtime: bool = True, loop: int = 1) -> FrameSource:
    """A :class:`FrameSource` of a camera index or ``/dev/videoN``, a URL or a video file (module doc).

    Parameters
    ----------
    source : int, str, os.PathLike or FrameSource
        ``0`` (a camera index), ``/dev/video0``, ``rtsp://...`` (any URL FFmpeg reads), a video file, or
        a :class:`PushSource` (returned as it is).
    realtime : bool
        A file is played at its own frame rate (default); False: as fast as it decodes.
    loop : int
        A file is played this many times.

    Returns
    -------
    FrameSource

    Raises
    ------
    facetex.BadInputError
        The camera is not available, the URL cannot be opened; a file's errors (missing,
        unreadable, no video stream) name it.
    """
    if isinstance(source, FrameSource):  # already open (a PushSource)
        return source
    kind = source_kind(source)
    if kind == "camera":
        return _camera(source)
    if kind == "url":
        return _url(str(source))
    return _file(source, realtime=realtime, loop=loop)
