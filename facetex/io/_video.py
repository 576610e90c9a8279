"""Video: reading frames with PyAV, writing H.264 (with the driver's audio), transcoding audio."""

from __future__ import annotations

import itertools
import math
import os
import warnings
from fractions import Fraction
from pathlib import Path
from typing import Callable, Iterable, Iterator

import av
import numpy as np

from ..errors import BadInputError, BadVideoError, FacetexError, OutputError
from ._atomic import VIDEO_EXTENSIONS, atomic_path, check_output_path
from ._convert import to_uint8
from ._files import _cause, _check_file

# ------------------------------------------------------------------------------ video
_AV_ERRORS = (av.FFmpegError, OSError, ValueError, EOFError)


def _open_input(path: Path, error: type = BadVideoError):
    _check_file(path, error)
    try:
        return av.open(os.fspath(path))
    except _AV_ERRORS as e:
        raise error(f"not a readable video ({_cause(e)}): "
                    "give an MP4/MOV/MKV/AVI file", path=path) from None


def _video_stream(container, path: Path):
    if not container.streams.video:
        container.close()
        raise BadVideoError("no video stream in this file: give a video", path=path)
    return container.streams.video[0]


def display_turns(rotation) -> int:
    """Quarter turns counter-clockwise (0-3) that show a decoded frame upright, from its display
    matrix's rotation in degrees (``av.VideoFrame.rotation``: FFmpeg's ``av_display_rotation_get``,
    counter-clockwise; a phone's portrait clip is stored landscape with -90, shown turned a quarter
    clockwise, as FFmpeg's own autorotation does). Angles between quarters are rounded to the nearest."""
    return int(round(float(rotation or 0) / 90.0)) % 4


def _first_frame_turns(c, s) -> int:
    """The first decodable frame's :func:`display_turns` (0 when none decodes: the readers report that)."""
    try:
        for frame in c.decode(s):
            return display_turns(frame.rotation)
    except _AV_ERRORS:
        pass
    return 0


def video_info(path) -> dict:
    """fps, n_frames, width, height, has_audio, duration (s) and rotation of a video file.

    n_frames comes from the container header, or from counting packets (no decoding). width and
    height are those of the frames as shown (and as :func:`iter_video_frames` yields them):
    swapped for a clip whose display matrix turns it a quarter (a phone's portrait video);
    ``rotation`` is that turn in degrees counter-clockwise (0, 90, 180 or 270), read from the
    first frame."""
    path = Path(path)
    with _open_input(path) as c:
        s = _video_stream(c, path)
        fps = float(s.average_rate or s.guessed_rate or 0)
        try:
            n = s.frames or sum(1 for p in c.demux(s) if p.size)
        except _AV_ERRORS as e:
            raise BadVideoError(f"corrupt video ({_cause(e)}): re-export or replace it", path=path) from None
        if s.duration is not None and s.time_base is not None:
            duration = float(s.duration * s.time_base)
        elif c.duration is not None:
            duration = c.duration / av.time_base
        else:
            duration = n / fps if fps else 0.0
        w, h = s.codec_context.width, s.codec_context.height
        with _open_input(path) as c2:  # decoding a frame here would move the packet count's demuxer
            turns = _first_frame_turns(c2, c2.streams.video[0])
        if turns % 2:
            w, h = h, w
        return dict(fps=fps, n_frames=int(n), width=w, height=h, has_audio=bool(c.streams.audio),
                    duration=duration, rotation=90 * turns)


def iter_video_frames(path, *, max_frames: int | None = None, uint8: bool = False,
                      max_side: int | None = None) -> Iterator[np.ndarray]:
    """Yield frames as float32 RGB (H, W, 3) in [0, 1] (``uint8``: as decoded, uint8 RGB), upright:
    turned as their display matrix says (:func:`display_turns`; a phone's portrait clip is stored
    landscape and would show every face on its side). ``max_side``: frames with a longer side
    above it are scaled down to it as they are converted (area averaging; an 8K frame is never
    held at full size in RGB).

    A damaged file that still decodes some frames yields those, then warns
    (UserWarning) and stops; one that decodes none raises BadVideoError."""
    path = Path(path)
    n, error = 0, ""
    # Frame threading is fast but drops the frames it holds when a later packet is
    # corrupt, so after an error the file is decoded again, packet by packet, without it.
    for threads in ("AUTO", "SLICE"):
        c = _open_input(path)
        try:
            s = _video_stream(c, path)
            s.thread_type = threads
            k, packets = 0, c.demux(s)
            while True:
                try:
                    packet = next(packets, None)
                    if packet is None:
                        break
                    frames = s.decode(packet)
                except _AV_ERRORS as e:
                    error = f" ({_cause(e)})"
                    if threads == "AUTO":
                        break
                    continue  # skip the corrupt packet; the final flush packet still comes
                for frame in frames:
                    k += 1
                    if k <= n:  # already yielded by the threaded pass
                        continue
                    if max_frames is not None and n >= max_frames:
                        return
                    n += 1
                    turns = display_turns(frame.rotation)  # (a reformatted frame has no side data)
                    if max_side is not None and max(frame.width, frame.height) > max_side:
                        f = max_side / max(frame.width, frame.height)
                        frame = frame.reformat(width=max(2, round(frame.width * f)),
                                               height=max(2, round(frame.height * f)), format="rgb24",
                                               interpolation="AREA")
                    rgb = frame.to_ndarray(format="rgb24")
                    if turns:
                        rgb = np.ascontiguousarray(np.rot90(rgb, turns))
                    yield rgb if uint8 else rgb.astype(np.float32) / 255.0
            if not error or threads == "SLICE":
                break
        finally:
            c.close()
    if n == 0 and max_frames != 0:
        raise BadVideoError(f"truncated or corrupt video, no decodable frame{error}: "
                            "re-export or replace it", path=path)
    if error or n < (s.frames or 0):  # the header declares more frames than decoded
        warnings.warn(f"{path}: video damaged, decoded {n} of {s.frames or '?'} frames{error}",
                      stacklevel=2)


def read_video(path, *, max_frames: int | None = None,
               progress: Callable | None = None) -> tuple[list[np.ndarray], float]:
    """All frames (float32 RGB) and the frame rate of a video.

    Parameters
    ----------
    path : str or os.PathLike
        The video file.
    max_frames : int, optional
        Read at most this many frames.
    progress : callable, optional
        Called with ``n=1`` per decoded frame.

    Returns
    -------
    frames : list of numpy.ndarray
        The frames, float32 (H, W, 3) in [0, 1].
    fps : float
        The frame rate.

    Raises
    ------
    facetex.BadVideoError
        Missing, unreadable file or no video stream."""
    fps = video_info(path)["fps"]
    frames = []
    for f in iter_video_frames(path, max_frames=max_frames):
        frames.append(f)
        if progress:
            progress(n=1)
    return frames, fps


def _audio_packets(src, out):
    """Yield (time_s, packet) of ``src``'s first audio stream ready to mux into ``out``:
    AAC is remuxed losslessly, anything else is re-encoded to AAC."""
    a = src.streams.audio[0]
    if a.codec_context.name == "aac":
        o = out.add_stream_from_template(a)
        start = None
        for p in src.demux(a):
            if p.dts is None or p.pts is None:
                continue
            start = p.pts if start is None else start
            p.pts, p.dts = p.pts - start, p.dts - start
            t = float(p.pts * p.time_base)
            p.stream = o
            yield t, p
        return
    o = out.add_stream("aac", rate=a.rate or 44100)
    o.layout = "mono" if a.codec_context.channels == 1 else "stereo"  # more channels are downmixed
    for frame in src.decode(a):
        t = float(frame.time) if frame.time is not None else 0.0
        frame.pts = None  # the encoder's resampler re-times frames from zero
        for p in o.encode(frame):
            yield float(p.pts * p.time_base) if p.pts is not None else t, p
    for p in o.encode(None):
        yield float(p.pts * p.time_base) if p.pts is not None else 0.0, p


def transcode_audio(src, dst) -> Path | None:
    """Write the first audio stream of video ``src`` to the scratch file ``dst`` (.m4a) as
    AAC (remuxed if it is AAC already), for :func:`write_video` to remux later: the encoding
    can then run while nothing else does. ``dst`` is an intermediate, not an output (not
    listed by :func:`committed_outputs`; removed if the transcoding fails or is interrupted).
    None if ``src`` has no decodable audio; the caller then passes ``src`` itself, whose
    problems :func:`write_video` reports."""
    src, dst = Path(src), Path(dst)
    try:
        with av.open(os.fspath(src)) as c:
            if not c.streams.audio:
                return None
        if _audio_error(src) is not None:
            return None
        with av.open(os.fspath(src)) as c, av.open(os.fspath(dst), "w", format="mp4") as out:
            for _, packet in _audio_packets(c, out):
                out.mux(packet)
    except BaseException as e:
        dst.unlink(missing_ok=True)
        if isinstance(e, (*_AV_ERRORS, FacetexError)):
            return None
        raise
    return dst


#: frames up to this many pixels (a 1080p driver side by side) are encoded with libx264's defaults;
#: larger ones with few look-ahead and reference frames on one thread: the encoder keeps ~40 frames
#: at ~4 bytes a pixel (1.3 GB at 4096 x 2304 after 30 frames; 0.5 GB so), issue 23
ENCODER_FULL_PIXELS = 3840 * 1080


#: libx264's macroblock-tree rate control made this PyAV build encode the same frames differently
#: from run to run (decoded frames up to 45/255 apart; also on one thread and without threaded
#: look-ahead: 40 frames of 180 x 144); without it every run writes the same video
DETERMINISTIC_X264 = "mbtree=0"


def _encoder_options(codec: str, pixels: int) -> dict:
    if codec != "libx264":
        return {}
    large = ":rc-lookahead=5:ref=1:bframes=1" if pixels > ENCODER_FULL_PIXELS else ""
    return {"x264-params": DETERMINISTIC_X264 + large}


def _prep_frame(f, shape) -> np.ndarray:
    u = to_uint8(f)
    if u.ndim == 2:
        u = np.repeat(u[..., None], 3, axis=2)
    if u.shape[:2] != shape[:2] or u.ndim != 3 or u.shape[2] != 3:
        raise BadInputError(f"video frame of shape {u.shape} differs from the first frame {shape}")
    # yuv420p needs even sizes: pad by repeating the last row/column (keeps every pixel)
    ph, pw = shape[0] % 2, shape[1] % 2
    return np.pad(u, ((0, ph), (0, pw), (0, 0)), mode="edge") if ph or pw else u


class _SourceError(Exception):
    """An error while reading the audio source (not while encoding the output)."""


def _audio_error(path: Path) -> str | None:
    """None if the first audio stream of ``path`` decodes from start to end, else the cause."""
    try:
        with av.open(os.fspath(path)) as c:
            a = c.streams.audio[0]
            n = 0
            for packet in c.demux(a):
                for _ in a.decode(packet):
                    n += 1
            return None if n else "no decodable audio frame"
    except _AV_ERRORS as e:
        return _cause(e)


def write_video(path, frames: Iterable[np.ndarray], fps: float, *, audio_from=None, crf: int = 18,
                overwrite: bool = True, progress: Callable | None = None, inputs=(),
                encoder_options: dict | None = None) -> Path:
    """Write RGB frames as H.264 video (.mp4, .mov, .m4v or .mkv), atomically.

    Encoder: libx264 (yuv420p, ``crf``); if this PyAV build lacks it, FFmpeg's default
    H.264 encoder (codec id lookup, e.g. libopenh264; ``crf`` may be ignored). Odd
    widths/heights are padded to even by repeating the last row/column, so the file
    is up to 1 px larger.

    Parameters
    ----------
    path : str or os.PathLike
        The output video.
    frames : iterable of numpy.ndarray
        (H, W, 3) float [0, 1] or uint8; an iterator is streamed.
    fps : float
        Frame rate.
    audio_from : str or os.PathLike, optional
        A file whose audio stream is passed through (AAC remuxed, other codecs re-encoded to
        AAC), starting with the video and trimmed to its length; a file without audio adds
        none, one whose audio cannot be decoded gives a video without audio and a warning.
    crf : int
        libx264's constant rate factor.
    overwrite : bool
        False: an exclusive create (an existing file is never replaced).
    progress : callable, optional
        Called with ``n=1`` per written frame.
    inputs : sequence of path
        Files the output must not be.
    encoder_options : dict, optional
        Further options of the encoder (FFmpeg's names), e.g. ``{"preset": "veryfast", "tune":
        "zerolatency"}`` for a live recording.

    Returns
    -------
    pathlib.Path
        The written file.

    Raises
    ------
    facetex.BadVideoError
        ``audio_from`` cannot be read (naming it).
    facetex.OutputError
        Encoding or writing failed (naming the output).
    """
    srcs = tuple(inputs or ()) + ((audio_from,) if audio_from is not None else ())
    path = check_output_path(path, overwrite=overwrite, inputs=srcs, extensions=VIDEO_EXTENSIONS, what="video")
    if not fps or not math.isfinite(fps) or fps <= 0:
        raise BadInputError(f"fps must be positive, not {fps}", path=path)
    src = None
    if audio_from is not None:
        audio_from = Path(audio_from)
        src = _open_input(audio_from)
        if not src.streams.audio:
            src.close()
            src = None
        else:
            cause = _audio_error(audio_from)
            if cause is not None:
                src.close()
                src = None
                warnings.warn(f"{audio_from}: its audio cannot be decoded ({cause}): the output has no audio",
                              stacklevel=2)
    it = iter(frames)
    try:
        first = next(it)
    except StopIteration:
        if src is not None:
            src.close()
        raise BadInputError("no frames to write", path=path) from None
    first = to_uint8(first)  # from here: a float frame is not kept through the run (the same values)
    shape = first.shape
    rate = Fraction(fps).limit_denominator(100_000)
    try:
        with atomic_path(path, overwrite=overwrite, inputs=srcs) as tmp, \
                av.open(os.fspath(tmp), "w", options={"movflags": "+faststart"}) as out:
            codec = "libx264" if "libx264" in av.codecs_available else "h264"
            vs = out.add_stream(codec, rate=rate)
            vs.height, vs.width = shape[0] + shape[0] % 2, shape[1] + shape[1] % 2
            vs.pix_fmt = "yuv420p"
            opts = {"crf": str(int(crf)), **_encoder_options(codec, vs.width * vs.height)}
            for k, v in (encoder_options or {}).items():  # the caller's x264-params after ours
                opts[str(k)] = f"{opts[k]}:{v}" if k == "x264-params" and k in opts else str(v)
            vs.options = opts
            if vs.width * vs.height > ENCODER_FULL_PIXELS:
                vs.codec_context.thread_count = 1
            audio = pending = None

            def next_audio():
                try:
                    return next(audio, None)
                except _AV_ERRORS as e:
                    raise _SourceError(_cause(e)) from None

            if src is not None:
                audio = _audio_packets(src, out)
                pending = next_audio()  # creates the audio stream before encoding starts

            def mux_audio(until: float):
                nonlocal pending
                while pending is not None and pending[0] < until:
                    out.mux(pending[1])
                    pending = next_audio()

            n = 0
            for f in itertools.chain([first], it):
                vf = av.VideoFrame.from_ndarray(_prep_frame(f, shape), format="rgb24")
                vf.pts = n
                vf.time_base = 1 / rate
                out.mux(vs.encode(vf))
                n += 1
                mux_audio(n / float(rate))
                if progress:
                    progress(n=1)
            out.mux(vs.encode(None))
            mux_audio(n / float(rate))  # audio is trimmed at the video's end
            if audio is not None:
                audio.close()
    except _SourceError as e:
        raise BadVideoError(f"damaged audio ({e}): re-export the video or strip its audio",
                            path=audio_from) from None
    except FacetexError:
        raise
    except (av.FFmpegError, OSError, ValueError) as e:
        raise OutputError(f"video encoding failed ({_cause(e)})", path=path) from None
    finally:
        if src is not None:
            src.close()
    return path
