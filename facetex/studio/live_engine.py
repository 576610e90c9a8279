"""The Live page's engine, behind one small interface (the swap point for ``facetex.live``).

The WebSocket endpoint (:mod:`facetex.studio.live`) needs only this::

    engine = make_live_engine(persona_path, size=256, mode="composite")
    puppet = engine.process(frame_rgb)   # uint8 (H, W, 3) in; uint8 (h, w, 3) out, or None
    engine.close()

``process`` returns the puppet frame (longer side ``size``), or None when the frame shows no
usable face. A streaming engine built for the camera (``facetex.live``) replaces
:class:`OneFrameClipEngine` by changing :func:`make_live_engine` alone.

Until then, :class:`OneFrameClipEngine` is an *interim*: each camera frame is puppeted as a
one-frame driver clip by the offline puppetry (:func:`facetex.puppet.puppetry.prepare_puppetry`
and :func:`~facetex.puppet.puppetry.render_frames`, the persona loaded and prepared once). The
puppet follows the camera's head pose and position and is composited into the camera frame
with its lighting; it does *not* follow the driver's expression, because a clip's motion is
measured against the clip's own mean and a one-frame clip is its own mean (the puppet shows its
average expression). It runs at ~3-4 frames a second on two cores (0.25-0.35 s a frame at 256 px,
measured on a GRID frame with a 33-photo persona): a real puppet frame per camera frame, slowly.
"""

from __future__ import annotations

import tempfile
import threading
from pathlib import Path
from typing import Protocol

import numpy as np

from ..errors import BadInputError, FacetexError, NoFaceError

MODES = ("composite", "face")


class LiveEngine(Protocol):
    """What the Live page's WebSocket needs of an engine."""

    def process(self, frame_rgb: np.ndarray) -> np.ndarray | None:
        """The puppet frame (uint8 RGB) for one camera frame (uint8 RGB), or None (no face)."""

    def close(self) -> None:
        """Free what the engine holds (threads, temporary files); optional: the endpoint calls it
        when the engine has it."""


def make_live_engine(persona_path, size: int, mode: str) -> LiveEngine:
    """The engine of one Live session: the swap point (see the module's docstring).

    Parameters
    ----------
    persona_path : str or os.PathLike
        The puppet's ``.persona`` file.
    size : int
        Longer side of the puppet frames in px (32..1024).
    mode : {"composite", "face"}
        The puppet put into the camera frame, or the puppet face alone on grey.

    Returns
    -------
    LiveEngine
        An object with ``process(frame_rgb) -> frame | None`` and ``close()``.

    Raises
    ------
    ValueError
        (:class:`facetex.BadInputError`) a bad size or mode; (:class:`facetex.BadPersonaError`)
        an unreadable persona.
    """
    if mode not in MODES:
        raise BadInputError(f"unknown live mode {mode!r}: use one of {', '.join(MODES)}")
    if not 32 <= int(size) <= 1024:
        raise BadInputError(f"live size must be 32..1024 px, got {size}")
    return OneFrameClipEngine(persona_path, int(size), mode)


class _Ready:
    """A finished future (what :func:`prepare_puppetry` takes as ``loading``)."""

    def __init__(self, value):
        self.value = value

    def result(self):
        return self.value


class OneFrameClipEngine:
    """Interim live engine: each frame puppeted as a one-frame clip by the offline puppetry
    (head pose and position follow the camera; the expression stays the persona's average).

    Parameters
    ----------
    persona_path : str or os.PathLike
        The puppet's ``.persona`` file (loaded and prepared once, here).
    size : int
        Longer side of the output frames in px.
    mode : {"composite", "face"}
        Composite into the camera frame, or the face alone.
    """

    def __init__(self, persona_path, size: int, mode: str):
        from ..puppet.params import PuppetParams
        from ..puppet.puppetry import load_puppet

        self.size, self.mode = size, mode
        self.params = PuppetParams()
        self._loaded = load_puppet(Path(persona_path), self.params)  # (persona, timings)
        self._dir = tempfile.TemporaryDirectory(prefix="facetex-live-")
        self._lock = threading.Lock()  # one frame at a time: the clip file is reused
        self._warm_up()

    def _warm_up(self) -> None:
        """One frame of a bundled portrait: the first frame's imports and caches (~5 s) are paid
        here, while the page says "loading", not on the user's first camera frame."""
        import cv2

        from .._resources import sample_path
        from ..io import read_image, to_uint8

        img = to_uint8(read_image(sample_path("frl_004_neutral.jpg")))
        h, w = img.shape[:2]
        self.process(cv2.resize(img, (320, round(320 * h / w)), interpolation=cv2.INTER_AREA))

    def process(self, frame_rgb: np.ndarray) -> np.ndarray | None:
        """The puppet frame for ``frame_rgb`` (uint8 (H, W, 3)), or None when no face is found."""
        from ..io import to_uint8, write_video
        from ..puppet.puppetry import prepare_puppetry, render_frames

        frame = np.ascontiguousarray(frame_rgb[..., :3], dtype=np.uint8)
        h, w = frame.shape[:2]
        frame = frame[: h - h % 2, : w - w % 2]  # H.264 needs even sides
        with self._lock:
            clip = Path(self._dir.name) / "frame.mp4"
            clip.unlink(missing_ok=True)
            write_video(clip, [frame], fps=25, crf=12)
            try:
                session = prepare_puppetry(clip, self._loaded[0], params=self.params, tracking="thread",
                                           loading=_Ready(self._loaded))
            except NoFaceError:
                return None
            rec = next(iter(render_frames(session, size=self.size, mode=self.mode, uint8_frame=True)), None)
        if rec is None or rec["lost"]:
            return None
        return rec["frame"] if rec["frame"].dtype == np.uint8 else to_uint8(rec["frame"])

    def close(self) -> None:
        try:
            self._dir.cleanup()
        except (OSError, FacetexError):
            pass
