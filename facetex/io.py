"""Image and video I/O: robust reading, atomic writing, PyAV video.

Images leave this module as float32 RGB in [0, 1], shape (H, W, 3). Every failure a
user can cause raises :class:`BadImageError` / :class:`BadVideoError` /
:class:`OutputError` with ``path`` set and a one-line cause.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import json
import os
import tempfile
import threading
import warnings
from fractions import Fraction
from io import BytesIO
from pathlib import Path
from typing import Callable, Iterable, Iterator

import av
import cv2
import numpy as np
from PIL import Image, ImageCms, ImageOps, UnidentifiedImageError

from .errors import BadImageError, BadInputError, BadVideoError, OutputError

__all__ = [
    "read_image", "read_image_uint8", "to_uint8", "to_float32",
    "atomic_path", "check_output_path", "write_image", "write_json",
    "video_info", "iter_video_frames", "read_video", "write_video",
]

_BACKGROUNDS = {"white": 1.0, "black": 0.0}
_PIL_LIMIT_LOCK = threading.Lock()  # guards our brief change of Pillow's global pixel limit
_ALPHA_MODES = {"RGBA", "LA", "PA", "RGBa", "La"}
_UMASK = os.umask(0o022)
os.umask(_UMASK)


# ----------------------------------------------------------------------------- images
def to_float32(img: np.ndarray) -> np.ndarray:
    """uint8 / uint16 / float image -> float32 in [0, 1] (integers scaled by their max)."""
    img = np.asarray(img)
    if img.dtype == np.uint8:
        return img.astype(np.float32) / 255.0
    if img.dtype == np.uint16:
        return img.astype(np.float32) / 65535.0
    return img.astype(np.float32, copy=False)


def to_uint8(img: np.ndarray) -> np.ndarray:
    """float [0, 1] (clipped) / uint16 / uint8 image -> uint8, rounded to nearest."""
    img = np.asarray(img)
    if img.dtype == np.uint8:
        return img
    if img.dtype == np.uint16:
        return ((img.astype(np.uint32) + 128) // 257).astype(np.uint8)
    return np.clip(np.rint(np.asarray(img, np.float32) * 255.0), 0, 255).astype(np.uint8)


def _cause(e: BaseException) -> str:
    return str(e).splitlines()[0] if str(e).strip() else type(e).__name__


def _check_file(path: Path, error: type) -> None:
    if not path.exists():
        raise error("file not found: check the path", path=path)
    if path.is_dir():
        raise error("is a directory, not a file: give a file path", path=path)
    if path.stat().st_size == 0:
        raise error("empty file (0 bytes): re-export or replace it", path=path)


def _apply_orientation(arr: np.ndarray, orientation: int) -> np.ndarray:
    """Numpy twin of ImageOps.exif_transpose, for arrays Pillow cannot hold (16-bit RGB)."""
    ops = {2: lambda a: a[:, ::-1], 3: lambda a: a[::-1, ::-1], 4: lambda a: a[::-1],
           5: lambda a: a.swapaxes(0, 1), 6: lambda a: np.rot90(a, -1),
           7: lambda a: a.swapaxes(0, 1)[::-1, ::-1], 8: lambda a: np.rot90(a, 1)}
    return np.ascontiguousarray(ops[orientation](arr)) if orientation in ops else arr


def _rawmode(im: Image.Image) -> str:
    tile = getattr(im, "tile", None) or []
    args = tile[0].args if tile else ""
    return args if isinstance(args, str) else str(args[0] if args else "")


def _composite(rgb: np.ndarray, alpha: np.ndarray | None, bg: float) -> np.ndarray:
    if alpha is None:
        return rgb
    a = alpha[..., None]
    return rgb * a + np.float32(bg) * (1.0 - a)


def _decode_16bit(path: Path, im: Image.Image) -> tuple[np.ndarray, np.ndarray | None]:
    # Pillow truncates 16-bit RGB(A)/LA to 8 bits, so OpenCV decodes these losslessly.
    arr = cv2.imdecode(np.fromfile(path, np.uint8), cv2.IMREAD_UNCHANGED)  # any path encoding
    if arr is None:
        raise BadImageError("corrupt or truncated 16-bit image: re-export or replace it", path=path)
    orientation = int(im.getexif().get(0x0112, 1) or 1)
    if im.format == "TIFF":
        # OpenCV 5 orients TIFF itself (all 8 values, even with IMREAD_IGNORE_ORIENTATION);
        # the stored-size check catches builds that do not, for the axis-swapping ones.
        stored = (im.tag_v2.get(257), im.tag_v2.get(256))
        if orientation >= 5 and stored[0] != stored[1] and arr.shape[:2] == stored:
            arr = _apply_orientation(arr, orientation)
    else:  # IMREAD_UNCHANGED ignores a PNG's eXIf orientation
        arr = _apply_orientation(arr, orientation)
    f = to_float32(arr)
    if f.ndim == 2:
        return np.repeat(f[..., None], 3, axis=2), None
    if f.shape[2] == 2:
        return np.repeat(f[..., :1], 3, axis=2), f[..., 1]
    return f[..., 2::-1], (f[..., 3] if f.shape[2] == 4 else None)


def _cmyk_to_rgb(im: Image.Image) -> Image.Image:
    # The embedded press profile gives far better colours than Pillow's naive formula;
    # Pillow already undoes Adobe's inverted CMYK, so neither path comes out inverted.
    icc = im.info.get("icc_profile")
    if icc:
        try:
            src = ImageCms.ImageCmsProfile(BytesIO(icc))
            if src.profile.xcolor_space.strip() == "CMYK":
                return ImageCms.profileToProfile(im, src, ImageCms.createProfile("sRGB"), outputMode="RGB")
        except (ImageCms.PyCMSError, OSError, ValueError):
            pass  # a broken profile: fall back to the formula
    return im.convert("RGB")


def _decode_pil(im: Image.Image) -> tuple[np.ndarray, np.ndarray | None]:
    im.load()
    im = ImageOps.exif_transpose(im)
    if im.mode == "CMYK":
        return np.asarray(_cmyk_to_rgb(im), np.float32) / 255.0, None
    if im.mode in ("I", "F"):  # 32-bit gray: assume 16-bit range for integers
        g = np.asarray(im, np.float32) / (65535.0 if im.mode == "I" else 1.0)
        return np.repeat(np.clip(g, 0, 1)[..., None], 3, axis=2), None
    if im.mode in _ALPHA_MODES or "transparency" in im.info:
        rgba = np.asarray(im.convert("RGBA"), np.float32) / 255.0
        return rgba[..., :3], rgba[..., 3]
    return np.asarray(im.convert("RGB"), np.float32) / 255.0, None


def read_image(path, *, background: str = "white", max_pixels: int = 150_000_000,
               min_size: int = 16) -> np.ndarray:
    """Read any common image as float32 RGB (H, W, 3) in [0, 1].

    EXIF orientation is applied; alpha / palette transparency is composited on
    ``background`` ("white" or "black"); 16-bit PNG/TIFF keep their precision;
    CMYK uses the embedded ICC profile when there is one. The declared size is
    checked against ``max_pixels`` from the header, before any pixel is decoded.
    """
    if background not in _BACKGROUNDS:
        raise BadInputError(f"background must be 'white' or 'black', not {background!r}")
    path = Path(path)
    _check_file(path, BadImageError)
    try:
        with _PIL_LIMIT_LOCK:  # our own limit below replaces Pillow's bomb check
            old, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
            try:
                im = Image.open(path)
            finally:
                Image.MAX_IMAGE_PIXELS = old
    except UnidentifiedImageError:
        raise BadImageError("not an image file (unrecognised format): give a JPEG/PNG/TIFF/WebP",
                            path=path) from None
    except (OSError, SyntaxError, ValueError) as e:
        raise BadImageError(f"corrupt image header ({_cause(e)}): re-export or replace it", path=path) from None
    with im:
        w, h = im.size
        if w * h > max_pixels:
            raise BadImageError(f"declared size {w}x{h} = {w * h} pixels exceeds the limit of "
                                f"{max_pixels} (decompression bomb?): downscale it or raise max_pixels",
                                path=path)
        if min(w, h) < min_size:
            raise BadImageError(f"image is {w}x{h} px, smaller than {min_size} px on a side: "
                                "use a larger image", path=path)
        try:
            if ";16" in _rawmode(im) or im.mode.startswith("I;16"):
                rgb, alpha = _decode_16bit(path, im)
            else:
                rgb, alpha = _decode_pil(im)
        except BadImageError:
            raise
        except (OSError, SyntaxError, ValueError, EOFError, IndexError) as e:
            raise BadImageError(f"corrupt or truncated image ({_cause(e)}): re-export or replace it",
                                path=path) from None
    out = _composite(rgb, alpha, _BACKGROUNDS[background])
    return np.ascontiguousarray(np.clip(out, 0.0, 1.0), dtype=np.float32)


def read_image_uint8(path, **kwargs) -> np.ndarray:
    """:func:`read_image` as uint8 RGB (H, W, 3)."""
    return to_uint8(read_image(path, **kwargs))


# ---------------------------------------------------------------------------- writing
@contextlib.contextmanager
def atomic_path(path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same extension); rename it over ``path``
    with os.replace on success, delete it on any exception (KeyboardInterrupt too)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent or ".")
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600 files
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def check_output_path(path, *, overwrite: bool = False) -> Path:
    """Raise OutputError unless ``path`` can be written (folder exists and is writable,
    the file is absent or ``overwrite``)."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        if folder.exists():
            raise OutputError(f"{folder} is a file, not a folder: choose another output path", path=path)
        raise OutputError(f"output folder {folder} does not exist: create it first", path=path)
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"output folder {folder} is not writable: choose another folder", path=path)
    if path.is_dir():
        raise OutputError("output path is a directory: give a file name", path=path)
    if path.exists() and not overwrite:
        raise OutputError("output file exists: pass --overwrite to replace it", path=path)
    return path


_IMAGE_EXTS = {".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg", ".tif": "tiff", ".tiff": "tiff",
               ".webp": "webp"}


def write_image(path, image: np.ndarray, *, overwrite: bool = True, quality: int = 95,
                bit_depth: int = 8) -> Path:
    """Write float [0, 1] / uint8 / uint16 RGB (or gray 2-D, or RGBA) atomically.

    The format follows the extension (.png .jpg .jpeg .tif .tiff .webp);
    ``bit_depth=16`` writes 16-bit PNG/TIFF. ``quality`` applies to JPEG and WebP.
    """
    path = check_output_path(path, overwrite=overwrite)
    fmt = _IMAGE_EXTS.get(path.suffix.lower())
    if fmt is None:
        raise OutputError(f"unknown image extension {path.suffix!r}: use one of "
                          f"{', '.join(sorted(_IMAGE_EXTS))}", path=path)
    if bit_depth not in (8, 16) or (bit_depth == 16 and fmt not in ("png", "tiff")):
        raise BadInputError(f"bit_depth {bit_depth} not possible for {fmt}: use 8, or 16 with .png/.tif",
                            path=path)
    img = np.asarray(image)
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (1, 3, 4)) or img.size == 0:
        raise BadInputError(f"cannot write image of shape {img.shape}: need (H,W), (H,W,3) or (H,W,4)",
                            path=path)
    if bit_depth == 16:
        img = img if img.dtype == np.uint16 else np.clip(np.rint(to_float32(img) * 65535), 0, 65535
                                                         ).astype(np.uint16)
    else:
        img = to_uint8(img)
    if img.ndim == 3 and img.shape[2] >= 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR if img.shape[2] == 3 else cv2.COLOR_RGBA2BGRA)
    params = {"jpeg": [cv2.IMWRITE_JPEG_QUALITY, int(quality)],
              "webp": [cv2.IMWRITE_WEBP_QUALITY, int(quality)]}.get(fmt, [])
    ok, buf = cv2.imencode(path.suffix, img, params)
    if not ok:
        raise OutputError(f"OpenCV could not encode {fmt}", path=path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.tobytes())
    return path


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, os.PathLike):
        return os.fspath(o)
    if dataclasses.is_dataclass(o) and not isinstance(o, type):
        return dataclasses.asdict(o)
    if isinstance(o, (set, frozenset, tuple)):
        return list(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_json(path, obj, *, overwrite: bool = True) -> Path:
    """Write ``obj`` as indented JSON atomically (numpy scalars/arrays, paths, dataclasses converted)."""
    path = check_output_path(path, overwrite=overwrite)
    text = json.dumps(obj, indent=2, default=_json_default) + "\n"
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


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


def video_info(path) -> dict:
    """fps, n_frames, width, height, has_audio, duration (s) of a video file.

    n_frames comes from the container header, or from counting packets (no decoding)."""
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
        return dict(fps=fps, n_frames=int(n), width=s.codec_context.width,
                    height=s.codec_context.height, has_audio=bool(c.streams.audio),
                    duration=duration)


def iter_video_frames(path, *, max_frames: int | None = None) -> Iterator[np.ndarray]:
    """Yield frames as float32 RGB (H, W, 3) in [0, 1].

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
                    yield frame.to_ndarray(format="rgb24").astype(np.float32) / 255.0
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
    """All frames (float32 RGB) and the frame rate of a video."""
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


def _prep_frame(f, shape) -> np.ndarray:
    u = to_uint8(f)
    if u.ndim == 2:
        u = np.repeat(u[..., None], 3, axis=2)
    if u.shape[:2] != shape[:2] or u.ndim != 3 or u.shape[2] != 3:
        raise BadInputError(f"video frame of shape {u.shape} differs from the first frame {shape}")
    # yuv420p needs even sizes: pad by repeating the last row/column (keeps every pixel)
    ph, pw = shape[0] % 2, shape[1] % 2
    return np.pad(u, ((0, ph), (0, pw), (0, 0)), mode="edge") if ph or pw else u


def write_video(path, frames: Iterable[np.ndarray], fps: float, *, audio_from=None, crf: int = 18,
                overwrite: bool = True, progress: Callable | None = None) -> Path:
    """Write RGB frames (float [0,1] or uint8; an iterator is streamed) as H.264 MP4.

    Encoder: libx264 (yuv420p, ``crf``); if this PyAV build lacks it, FFmpeg's default
    H.264 encoder (codec id lookup, e.g. libopenh264; ``crf`` may be ignored). Odd
    widths/heights are padded to even by repeating the last row/column, so the file
    is up to 1 px larger. If ``audio_from`` has an audio stream, it is passed through
    (AAC remuxed, other codecs re-encoded to AAC), starting with the video and
    trimmed to its length; a file without audio adds none. Written atomically.
    """
    path = check_output_path(path, overwrite=overwrite)
    if not fps or fps <= 0:
        raise BadInputError(f"fps must be positive, not {fps}", path=path)
    it = iter(frames)
    try:
        first = next(it)
    except StopIteration:
        raise BadInputError("no frames to write", path=path) from None
    shape = to_uint8(first).shape
    src = _open_input(Path(audio_from)) if audio_from is not None else None
    rate = Fraction(fps).limit_denominator(100_000)
    try:
        with atomic_path(path) as tmp, av.open(os.fspath(tmp), "w",
                                               options={"movflags": "+faststart"}) as out:
            codec = "libx264" if "libx264" in av.codecs_available else "h264"
            vs = out.add_stream(codec, rate=rate)
            vs.height, vs.width = shape[0] + shape[0] % 2, shape[1] + shape[1] % 2
            vs.pix_fmt = "yuv420p"
            vs.options = {"crf": str(int(crf))}
            audio = pending = None
            if src is not None and src.streams.audio:
                audio = _audio_packets(src, out)
                pending = next(audio, None)  # creates the audio stream before encoding starts

            def mux_audio(until: float):
                nonlocal pending
                while pending is not None and pending[0] < until:
                    out.mux(pending[1])
                    pending = next(audio, None)

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
    except (av.FFmpegError, OSError) as e:
        raise OutputError(f"video encoding failed ({_cause(e)})", path=path) from None
    finally:
        if src is not None:
            src.close()
    return path
