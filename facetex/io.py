"""Image and video I/O: robust reading, atomic writing, PyAV video.

Images leave this module as float32 RGB in [0, 1], shape (H, W, 3). Every failure a
user can cause raises :class:`BadImageError` / :class:`BadVideoError` /
:class:`OutputError` with ``path`` set and a one-line cause.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import itertools
import json
import math
import os
import re
import stat
import tempfile
import threading
import warnings
from fractions import Fraction
from io import BytesIO
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterable, Iterator, TypeVar, Union

import av
import cv2
import numpy as np
from PIL import Image, ImageCms, ImageOps, UnidentifiedImageError
from struct import error as struct_error
from zlib import error as zlib_error

from .errors import BadImageError, BadInputError, BadVideoError, FacetexError, OutputError, not_found_error

if TYPE_CHECKING:
    from PIL.Image import Image as PILImage

__all__ = [
    "ImageLike", "as_image", "image_args", "read_image", "read_image_reduced", "read_image_uint8", "to_uint8",
    "to_float32", "check_input_file", "check_input_dir", "as_path", "read_regular", "atomic_path",
    "check_output_path", "check_outputs", "write_files", "temp_tag", "encode_image", "encode_json", "write_image",
    "write_json", "committed_outputs",
    "video_info", "iter_video_frames", "read_video", "write_video", "transcode_audio", "npz_members",
    "MAX_IMAGE_PIXELS", "DETECT_MAX_PIXELS", "IMAGE_MEMORY_BUDGET", "IMAGE_EXTENSIONS", "VIDEO_EXTENSIONS",
]

_BACKGROUNDS = {"white": 1.0, "black": 0.0}
_PIL_LIMIT_LOCK = threading.Lock()  # guards our brief change of Pillow's global pixel limit
_ALPHA_MODES = {"RGBA", "LA", "PA", "RGBa", "La"}
_UMASK = os.umask(0o022)
os.umask(_UMASK)


# ----------------------------------------------------------------------------- images
#: a path, a PIL image or an (H, W, 3) array (uint8, uint16, or float in [0, 1])
ImageLike = Union[str, os.PathLike, "PILImage", np.ndarray]


def as_image(image: ImageLike, name: str = "image") -> np.ndarray:
    """An image argument as float32 RGB (H, W, 3) in [0, 1].

    Parameters
    ----------
    image : str, os.PathLike, PIL.Image.Image or numpy.ndarray
        A file (read with :func:`facetex.read_image`: EXIF-rotated, alpha composited on
        white), a PIL image, or an array: uint8 / uint16 (scaled by their maximum), float
        in [0, 1], gray (H, W) or RGBA (H, W, 4) (alpha composited on white).
    name : str
        What the image is, for error messages ("content image").

    Returns
    -------
    numpy.ndarray
        The image, float32 (H, W, 3) in [0, 1].

    Raises
    ------
    FileNotFoundError
        (:class:`facetex.BadImageError`) the file does not exist.
    ValueError
        (:class:`facetex.BadImageError`) unreadable file, wrong shape or dtype, a float image
        in 0..255, NaN or infinite values.

    Examples
    --------
    >>> import numpy as np, facetex
    >>> facetex.as_image(np.zeros((40, 40, 3), np.uint8)).dtype
    dtype('float32')
    """
    if isinstance(image, (str, os.PathLike)):
        return read_image(image)
    if type(image).__module__.startswith("PIL.") and hasattr(image, "convert"):
        mode = image.mode
        rgba = "A" in mode or "transparency" in getattr(image, "info", {})
        image = np.asarray(image.convert("RGBA" if rgba else "RGB"))
    a = np.asarray(image)
    if a.dtype == bool or not (np.issubdtype(a.dtype, np.floating) or a.dtype in (np.uint8, np.uint16)):
        raise BadImageError(f"{name} has dtype {a.dtype}: give uint8, uint16 or float in [0, 1]")
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4):
        raise BadImageError(f"{name} must be an (H, W, 3) RGB image, got shape {a.shape}")
    if a.shape[0] == 0 or a.shape[1] == 0:
        raise BadImageError(f"{name} has no pixels (shape {a.shape})")
    if np.issubdtype(a.dtype, np.floating):
        check_float_pixels(a, name)
    f = to_float32(a)
    f = np.clip(f, 0.0, 1.0, out=f if f is not a else None)  # in place on a new copy: one float image, not two
    if f.shape[2] == 4:
        alpha = f[..., 3:]
        f = f[..., :3] * alpha + (1.0 - alpha)
    return np.ascontiguousarray(f, dtype=np.float32)


_F = TypeVar("_F", bound=Callable)


def image_args(*names: str, sources: dict[str, str] | None = None,
               arrays: str = "float") -> Callable[[_F], _F]:
    """Decorator: the named image parameters of a public function take every :data:`ImageLike`
    (a path, a PIL image, a uint8 / uint16 or float [0, 1] array), converted by
    :func:`as_image` (float32 RGB in [0, 1]; None passes through). ``sources`` maps an image
    parameter to the function's parameter naming its file for error messages, filled with the
    path when one is given. ``arrays="keep"``: uint8 (H, W, 3) arrays pass unchanged (callers
    that work in uint8, e.g. the detector on video frames, pay no conversion)."""
    import functools
    import inspect

    def wrap(fn: _F) -> _F:
        sig = inspect.signature(fn)

        @functools.wraps(fn)
        def inner(*args, **kwargs):
            bound = sig.bind(*args, **kwargs)
            for name in names:
                if name not in bound.arguments or bound.arguments[name] is None:
                    continue
                v = bound.arguments[name]
                if isinstance(v, (str, os.PathLike)) and sources and name in sources \
                        and bound.arguments.get(sources[name]) is None:
                    bound.arguments[sources[name]] = os.fspath(v)
                if arrays == "keep" and isinstance(v, np.ndarray) and v.dtype == np.uint8 and v.ndim == 3 \
                        and v.shape[2] == 3:
                    continue
                bound.arguments[name] = as_image(v, name=name.replace("_", " "))
            return fn(*bound.args, **bound.kwargs)

        return inner  # type: ignore[return-value]

    return wrap


def to_float32(img: np.ndarray) -> np.ndarray:
    """uint8 / uint16 / float image -> float32 in [0, 1] (integers scaled by their max)."""
    img = np.asarray(img)
    if img.dtype in (np.uint8, np.uint16):
        a = img.astype(np.float32)
        a /= 255.0 if img.dtype == np.uint8 else 65535.0  # in place: one float copy, not two
        return a
    return img.astype(np.float32, copy=False)


def _all_finite(a: np.ndarray) -> bool:
    """Whether every value of ``a`` is finite; a large array in row strips (no boolean
    temporary of its size: a 6000 x 6000 float64 image would need 108 MB)."""
    if a.ndim == 0 or a.size <= 1 << 22:
        return bool(np.all(np.isfinite(a)))
    rows = max(1, (1 << 22) // (a.size // a.shape[0]))
    return all(bool(np.all(np.isfinite(a[i:i + rows]))) for i in range(0, a.shape[0], rows))


def check_float_pixels(a: np.ndarray, name: str, *, slack: float = 1e-3, path=None) -> None:
    """BadImageError (naming ``path``) unless the float image ``a`` is finite and within
    [-slack, 1 + slack]; a 0..255 image is told to divide by 255."""
    if not _all_finite(a):
        what = "only NaN or infinite values" if not np.isfinite(a).any() else "NaN or infinite values"
        raise BadImageError(f"{name} contains {what}", path=path)
    lo, hi = float(a.min()), float(a.max())
    if hi > 1.0 + slack:
        hint = ": divide by 255 (facetex takes floats in [0, 1], or uint8)" if hi <= 255.5 else ""
        raise BadImageError(f"{name} is a float image with values up to {hi:.4g}, not in [0, 1]{hint}", path=path)
    if lo < -slack:
        raise BadImageError(f"{name} has negative values (min {lo:.4g}): give floats in [0, 1]", path=path)


def to_uint8(img: np.ndarray) -> np.ndarray:
    """float [0, 1] (clipped) / uint16 / uint8 image -> uint8, rounded to nearest."""
    img = np.asarray(img)
    if img.dtype == np.uint8:
        return img
    if img.dtype == np.uint16:
        return ((img.astype(np.uint32) + 128) // 257).astype(np.uint8)
    a = np.asarray(img, np.float32)
    if a.ndim == 0 or a.size <= 1 << 22:
        return np.clip(np.rint(a * 255.0), 0, 255).astype(np.uint8)
    out = np.empty(a.shape, np.uint8)  # a 36 MP image in strips: no float temporaries of its size
    rows = max(1, (1 << 22) // (a.size // a.shape[0]))
    for i in range(0, a.shape[0], rows):
        out[i:i + rows] = np.clip(np.rint(a[i:i + rows] * 255.0), 0, 255)
    return out


def _cause(e: BaseException) -> str:
    return str(e).splitlines()[0] if str(e).strip() else type(e).__name__


_FILE_KINDS = ((stat.S_ISFIFO, "a FIFO / named pipe"), (stat.S_ISCHR, "a character device"),
               (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _kind(mode: int) -> str:
    return next((name for test, name in _FILE_KINDS if test(mode)), "not a regular file")


def as_path(path, error: type = BadInputError, what: str = "file") -> Path:
    """``path`` as a Path, or ``error`` when it is not a path (None, a number, a BytesIO, a list)."""
    if isinstance(path, (str, os.PathLike)):
        return Path(path)
    hint = ": to read bytes in memory, open them with PIL.Image.open and pass that to facetex.as_image" \
        if hasattr(path, "read") else ""
    raise error(f"the {what} must be a path (str or os.PathLike), not {type(path).__name__}{hint}")


def _stat_error(path: Path, e: OSError, error: type, what: str):
    if e.errno == errno.ELOOP:
        return error("symlink loop: the path points back to itself; fix the link", path=path)
    if e.errno in (errno.ENOENT, errno.ENOTDIR):
        if os.path.islink(path):
            return error(f"broken symlink: its target does not exist ({os.readlink(path)})", path=path)
        return not_found_error(error)(f"{what} not found: check the path", path=path)
    if e.errno == errno.EACCES:
        return error(f"permission denied: cannot read this {what}", path=path)
    if e.errno == errno.ENAMETOOLONG:
        return error("file name too long", path=path)
    return error(f"cannot access this {what} ({e.strerror})", path=path)


def check_input_file(path, error: type = BadInputError, *, what: str = "file") -> Path:
    """Raise ``error`` (naming ``path``) unless it is a non-empty regular file (symlinks
    followed). FIFOs and devices are refused before anything opens them: reading a FIFO
    blocks and /dev/zero never ends."""
    path = as_path(path, error, what)
    try:
        st = os.stat(path)
    except OSError as e:
        raise _stat_error(path, e, error, what) from None
    except ValueError as e:  # NUL byte in the name
        raise error(f"invalid file name ({e})", path=path) from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"is a directory, not a file: give a {what} path", path=path)
    if not stat.S_ISREG(st.st_mode):
        raise error(f"not a regular file ({_kind(st.st_mode)}): give a {what}", path=path)
    if st.st_size == 0:
        raise error("empty file (0 bytes): re-export or replace it", path=path)
    return path


def read_regular(path, limit: int | None = None) -> bytes:
    """The bytes of ``path`` if it is a regular file, checked on the open file itself: not a
    symlink, and a FIFO is neither waited for nor read (OSError otherwise; also when it is
    larger than ``limit`` bytes)."""
    fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fh.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise OSError(errno.EINVAL, f"not a regular file ({_kind(st.st_mode)})", str(path))
        if limit is not None and st.st_size > limit:
            raise OSError(errno.EFBIG, f"larger than {limit} bytes", str(path))
        return fh.read()


def check_input_dir(path, error: type = BadInputError, *, what: str = "folder") -> Path:
    """Raise ``error`` (naming ``path``) unless it is a readable directory (symlinks followed)."""
    path = as_path(path, error, what)
    try:
        st = os.stat(path)
    except OSError as e:
        raise _stat_error(path, e, error, what) from None
    if not stat.S_ISDIR(st.st_mode):
        raise error(f"not a folder ({'a file' if stat.S_ISREG(st.st_mode) else _kind(st.st_mode)}): "
                    f"give a {what}", path=path)
    if not os.access(path, os.R_OK | os.X_OK):
        raise error(f"permission denied: cannot list this {what}", path=path)
    return path


def _check_file(path: Path, error: type) -> None:
    check_input_file(path, error)


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


def _decode_16bit(path: Path, im: Image.Image, out_size: tuple[int, int] | None
                  ) -> tuple[np.ndarray, np.ndarray | None]:
    # Pillow truncates 16-bit RGB(A)/LA to 8 bits, so OpenCV decodes these losslessly.
    arr = cv2.imdecode(np.fromfile(path, np.uint8), cv2.IMREAD_UNCHANGED)  # any path encoding
    if arr is None:
        raise BadImageError("corrupt or truncated 16-bit image: re-export or replace it", path=path)
    if out_size is not None:  # out_size is in stored axes; OpenCV may have turned a TIFF already
        turned = arr.shape[:2] == (im.size[0], im.size[1]) and im.size[0] != im.size[1]
        arr = cv2.resize(arr, out_size[::-1] if turned else out_size, interpolation=cv2.INTER_AREA)
    orientation = int(im.getexif().get(0x0112, 1) or 1)
    if im.format == "TIFF":
        # OpenCV 5 orients TIFF itself (all 8 values, even with IMREAD_IGNORE_ORIENTATION);
        # the stored-size check catches builds that do not, for the axis-swapping ones.
        stored = (im.tag_v2.get(257), im.tag_v2.get(256))
        if out_size is not None:
            stored = (out_size[1], out_size[0])
        if orientation >= 5 and stored[0] != stored[1] and arr.shape[:2] == stored:
            arr = _apply_orientation(arr, orientation)
    else:  # IMREAD_UNCHANGED ignores a PNG's eXIf orientation
        arr = _apply_orientation(arr, orientation)
    f = to_float32(arr)
    del arr
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


def _as_float(im: Image.Image) -> np.ndarray:
    a = np.asarray(im, np.float32)
    a /= 255.0  # in place: a 40 MP image must not hold two float copies
    return a


#: Pillow modes that ``Image.reduce`` handles without a full-size conversion first
_REDUCIBLE = {"L", "RGB", "I", "F", "CMYK", "RGBX"}


def _decode_pil(im: Image.Image, out_size: tuple[int, int] | None) -> tuple[np.ndarray, np.ndarray | None]:
    """``out_size``: (w, h) in stored (not displayed) axes to reduce to, or None."""
    im.load()
    icc = im.info.get("icc_profile")
    if out_size is not None and im.size != out_size:
        if im.mode not in _REDUCIBLE:
            im = im.convert("RGBA" if im.mode in _ALPHA_MODES or "transparency" in im.info else "RGB")
        factor = max(1, min(im.size[0] // out_size[0], im.size[1] // out_size[1]))
        small = im.reduce(factor) if factor > 1 else im
        small = small.resize(out_size, Image.Resampling.BOX) if small.size != out_size else small
        if small is not im:
            im.close()  # frees the full-size pixels now (the caller still holds the object)
        im = small
        if icc:
            im.info["icc_profile"] = icc
    im = ImageOps.exif_transpose(im)
    if im.mode == "CMYK":
        return _as_float(_cmyk_to_rgb(im)), None
    if im.mode in ("I", "F"):  # 32-bit gray: assume 16-bit range for integers
        g = np.asarray(im, np.float32) / (65535.0 if im.mode == "I" else 1.0)
        return np.repeat(np.clip(g, 0, 1)[..., None], 3, axis=2), None
    if im.mode in _ALPHA_MODES or "transparency" in im.info:
        rgba = _as_float(im.convert("RGBA"))
        return rgba[..., :3], rgba[..., 3]
    return _as_float(im if im.mode == "RGB" else im.convert("RGB")), None


#: Largest image read at full resolution (transfer content/style, metrics): 40 MP, e.g.
#: 7746 x 5164. Decoding it costs at most 16-20 bytes per pixel (Pillow's pixels plus float32 RGB).
MAX_IMAGE_PIXELS = 40_000_000
#: Images read only to find a face (landmarks, identity, persona photos and references) are
#: reduced on load to at most this many pixels (Pillow's JPEG draft mode decodes them smaller).
DETECT_MAX_PIXELS = 8_000_000
#: Memory one image may take while being decoded and converted; larger declared sizes are
#: refused from the header, before any pixel is decoded (decompression bombs).
IMAGE_MEMORY_BUDGET = 768 * 2**20


def _bytes_per_pixel(im: Image.Image, sixteen: bool) -> int:
    """Bytes per pixel of the decoded image: OpenCV's for 16-bit files; Pillow keeps any
    image of several bands in 4 bytes per pixel (RGB as RGBX)."""
    bands = len(im.getbands())
    if sixteen:
        return 2 * bands
    return 4 if bands > 1 or im.mode in ("I", "F") else 1


def read_image(path: str | os.PathLike, *, background: str = "white", max_pixels: int = MAX_IMAGE_PIXELS,
               min_size: int = 16, reduce_to: int | None = None) -> np.ndarray:
    """Read any common image as float32 RGB (H, W, 3) in [0, 1].

    EXIF orientation is applied; 16-bit PNG/TIFF keep their precision; CMYK uses the
    embedded ICC profile when there is one; an animated or multi-page image gives its first
    frame (with a warning). The declared size is checked from the header, before any pixel
    is decoded. Any image whose decoding would take more than :data:`IMAGE_MEMORY_BUDGET`
    is refused.

    Parameters
    ----------
    path : str or os.PathLike
        The image file.
    background : {"white", "black"}
        What alpha / palette transparency is composited on.
    max_pixels : int
        Larger images (by their header) are refused, unless ``reduce_to`` is given.
    min_size : int
        Images with a side below this many pixels are refused.
    reduce_to : int, optional
        Reduce the image on load to at most this many pixels (for face detection).

    Returns
    -------
    numpy.ndarray
        The image, float32 (H, W, 3) in [0, 1].

    Raises
    ------
    facetex.BadImageError
        Missing, unreadable, corrupt, too small or too large file (one line naming it).
    """
    return read_image_reduced(path, reduce_to, background=background, max_pixels=max_pixels,
                              min_size=min_size)[0]


def read_image_reduced(path, reduce_to: int | None = DETECT_MAX_PIXELS, *, background: str = "white",
                       max_pixels: int = MAX_IMAGE_PIXELS, min_size: int = 16
                       ) -> tuple[np.ndarray, tuple[float, float]]:
    """:func:`read_image` reduced on load to at most ``reduce_to`` pixels, and the scale
    (sx, sy) = returned size / the image's displayed size (1.0 when not reduced). A point
    (x, y) of the returned image is ((x + 0.5) / sx - 0.5, (y + 0.5) / sy - 0.5) in the original."""
    if background not in _BACKGROUNDS:
        raise BadInputError(f"background must be 'white' or 'black', not {background!r}")
    path = check_input_file(path, BadImageError, what="image file")
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
        if reduce_to is None and w * h > max_pixels:
            raise BadImageError(f"declared size {w}x{h} = {w * h} pixels exceeds the limit of "
                                f"{max_pixels} (decompression bomb?): downscale it", path=path)
        if min(w, h) < min_size:
            raise BadImageError(f"image is {w}x{h} px, smaller than {min_size} px on a side: "
                                "use a larger image", path=path)
        try:
            frames = int(getattr(im, "n_frames", 1) or 1)
        except (OSError, SyntaxError, ValueError, EOFError, struct_error):
            frames = 1
        if frames > 1 and im.format != "MPO":  # MPO: a camera JPEG with previews; frame 0 is the photo
            warnings.warn(f"{path}: animated or multi-page image ({frames} frames): the first frame is used",
                          stacklevel=2)
        sixteen = ";16" in _rawmode(im) or im.mode.startswith("I;16")
        out_size = None
        if reduce_to is not None and w * h > reduce_to:
            k = math.sqrt(w * h / reduce_to)
            out_size = (max(1, int(w / k)), max(1, int(h / k)))
            if im.format == "JPEG" and not sixteen:
                with contextlib.suppress(Exception):
                    im.draft(None, out_size)  # DCT scaling: decodes at 1/2, 1/4 or 1/8 size
        dw, dh = im.size  # after draft
        out_px = (out_size[0] * out_size[1]) if out_size else dw * dh
        need = dw * dh * _bytes_per_pixel(im, sixteen) + out_px * (16 if im.mode in _ALPHA_MODES else 12)
        if sixteen:
            need += path.stat().st_size  # OpenCV decodes from the file's bytes
        if out_size is not None and (sixteen or im.mode not in _REDUCIBLE):
            need += dw * dh * 4  # full-size conversion before the reduction
        if need > IMAGE_MEMORY_BUDGET:
            raise BadImageError(f"declared size {w}x{h} = {w * h} pixels needs about {need / 2**30:.1f} GiB "
                                f"to decode, over the limit of {IMAGE_MEMORY_BUDGET / 2**30:.2f} GiB per image "
                                "(decompression bomb?): downscale it", path=path)
        try:
            if sixteen:
                rgb, alpha = _decode_16bit(path, im, out_size)
            else:
                rgb, alpha = _decode_pil(im, out_size)
        except BadImageError:
            raise
        except (OSError, SyntaxError, ValueError, EOFError, IndexError, struct_error, zlib_error) as e:
            raise BadImageError(f"corrupt or truncated image ({_cause(e)}): re-export or replace it",
                                path=path) from None
        except MemoryError:
            raise BadImageError(f"out of memory decoding this {w}x{h} image: downscale it", path=path) from None
    out = _composite(rgb, alpha, _BACKGROUNDS[background])
    del rgb, alpha
    out = np.ascontiguousarray(out, dtype=np.float32)
    np.clip(out, 0.0, 1.0, out=out)
    oh, ow = out.shape[:2]
    turned = abs(ow / oh - h / w) < abs(ow / oh - w / h)  # EXIF orientations 5-8 swap the axes
    disp = (h, w) if turned else (w, h)
    scale = (ow / disp[0], oh / disp[1])
    return out, scale


def read_image_uint8(path, **kwargs) -> np.ndarray:
    """:func:`read_image` as uint8 RGB (H, W, 3)."""
    return to_uint8(read_image(path, **kwargs))


# ---------------------------------------------------------------------------- writing
# Every output is written to a temporary file beside its final name and then committed:
# without overwrite by a hard link to the final name, which fails if anything appeared
# there meanwhile (an exclusive create: nothing the user did not ask to replace is ever
# replaced); with overwrite by os.replace. Files written together (an image and its
# sidecar, an .obj with its .mtl and .png) are all written first and committed together,
# the committed ones rolled back if a later one fails.

IMAGE_EXTENSIONS = {".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg", ".tif": "tiff", ".tiff": "tiff",
                    ".webp": "webp"}
_IMAGE_EXTS = IMAGE_EXTENSIONS  # old name
#: containers write_video produces (H.264, AAC audio)
VIDEO_EXTENSIONS = (".mp4", ".mov", ".m4v", ".mkv")

_COMMITTED: list[Path] = []
_SEEN_ABSENT: set[str] = set()  # outputs found absent by an earlier check of this command
_APPEARED = ("output file appeared during the run (another process?): it was not replaced; "
             "pass --overwrite to replace it")
_COMMITTED_LOCK = threading.Lock()
_NO_HARD_LINKS = {errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK, errno.EXDEV, errno.ENOSYS}


def committed_outputs(*, reset: bool = False) -> list[Path]:
    """Files committed by this process since the last reset (the CLI resets it per command
    and names them when it is interrupted: an interrupted run never claims "no output" while
    it has left intermediate files)."""
    with _COMMITTED_LOCK:
        out = list(_COMMITTED)
        if reset:
            _COMMITTED.clear()
            _SEEN_ABSENT.clear()
    return out


def _write_error(path: Path, e: OSError) -> OutputError:
    code = getattr(e, "errno", None)
    why = e.strerror or _cause(e)
    if code in (errno.ENOSPC, errno.EDQUOT):
        return OutputError(f"disk full ({why}): nothing was written; free some space or write elsewhere", path=path)
    if code == errno.EROFS:
        return OutputError("read-only file system: choose another output folder", path=path)
    if code in (errno.EACCES, errno.EPERM):
        return OutputError(f"permission denied ({why}): choose another output folder", path=path)
    if code == errno.ENOENT:
        return OutputError("the output folder disappeared during the run (deleted?): create it again or "
                           "choose another", path=path)
    if code == errno.EFBIG:
        return OutputError("file too large for this file system: choose another output folder", path=path)
    return OutputError(f"cannot write the output ({why})", path=path)


def _same_file(a, b) -> bool:
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def _check_existing(path: Path, st: os.stat_result, inputs) -> None:
    """Refusals whatever ``overwrite`` says: a directory, a device / FIFO, an input."""
    if stat.S_ISDIR(st.st_mode):
        raise OutputError("output path is a directory: give a file name", path=path)
    if not stat.S_ISREG(st.st_mode):
        raise OutputError(f"output path is {_kind(st.st_mode)}, not a regular file: it is never replaced; "
                          "give a file name", path=path)
    for i in inputs or ():
        if i is not None and _same_file(path, i):
            raise OutputError(f"output is the same file as the input {i}: it would be destroyed; "
                              "choose another output name", path=path)


def check_output_path(path, *, overwrite: bool = False, inputs=(), extensions=None,
                      what: str = "output") -> Path:
    """Raise OutputError unless ``path`` can be written: its folder exists, is a folder and is
    writable; the path is not a directory, device or FIFO, not the same file as any of
    ``inputs`` (whatever ``overwrite`` says) and absent unless ``overwrite``; its extension
    (lower case) is one of ``extensions`` when given."""
    path = as_path(path, OutputError, what)

    def check_extension():
        if extensions is not None and path.suffix.lower() not in extensions:
            raise OutputError(f"unknown {what} extension {path.suffix or '(none)'!r}: use one of "
                              f"{', '.join(sorted(extensions))}", path=path)

    folder = path.parent
    try:
        fst = os.stat(folder)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise OutputError(f"output folder {folder} is a symlink loop: fix the link", path=path) from None
        if e.errno == errno.ENOTDIR:
            raise OutputError(f"{folder} is not a folder: choose another output path", path=path) from None
        raise OutputError(f"output folder {folder} does not exist: create it first", path=path) from None
    if not stat.S_ISDIR(fst.st_mode):
        raise OutputError(f"{folder} is a file, not a folder: choose another output path", path=path)
    if fst.st_nlink == 0:  # the (current) folder was deleted while we are in it
        raise OutputError(f"output folder {os.path.abspath(folder) if str(folder) != '.' else '(the current folder)'}"
                          " was deleted: create it again or change to an existing folder", path=path)
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"output folder {folder} is not writable: choose another folder", path=path)
    try:
        os.lstat(path)
    except FileNotFoundError:
        check_extension()
        with _COMMITTED_LOCK:
            _SEEN_ABSENT.add(os.path.abspath(path))
        return path
    except OSError as e:
        raise OutputError(f"cannot use this output path ({e.strerror})", path=path) from None
    try:
        st = os.stat(path)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise OutputError("output path is a symlink loop: remove it or choose another name", path=path) from None
        st = None  # a dangling symlink: the link itself is what would be replaced
    if st is not None:
        _check_existing(path, st, inputs)
    check_extension()
    if not overwrite:
        if os.path.abspath(path) in _SEEN_ABSENT:
            raise OutputError(_APPEARED, path=path)
        raise OutputError("output file exists: pass --overwrite to replace it", path=path)
    return path


def check_outputs(paths, *, overwrite: bool = False, inputs=()) -> list[Path]:
    """:func:`check_output_path` for every path, and no two of them the same."""
    out = [check_output_path(p, overwrite=overwrite, inputs=inputs) for p in paths]
    seen = set()
    for p in out:
        key = os.path.abspath(p)
        if key in seen:
            raise OutputError("the same output path is given twice: choose distinct names", path=p)
        seen.add(key)
    return out


_TEMP_TAG = ""  # see temp_tag()


@contextlib.contextmanager
def temp_tag(tag: str | None) -> Iterator[None]:
    """Temporary files made inside (by any thread) are named ``.<stem>.<tag>.<random><ext>``:
    a batch run puts its own tag there, so that it removes only temporaries it made, never a
    user's hidden file that merely looks like one."""
    global _TEMP_TAG
    if tag and not re.fullmatch(r"[A-Za-z0-9]+", tag):
        raise ValueError(f"a temporary-file tag is letters and digits, not {tag!r}")
    old, _TEMP_TAG = _TEMP_TAG, tag or ""
    try:
        yield
    finally:
        _TEMP_TAG = old


def _temp_beside(path: Path) -> Path:
    prefix = f".{path.stem}.{_TEMP_TAG}." if _TEMP_TAG else f".{path.stem}."
    try:
        fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=path.suffix, dir=path.parent)
    except OSError as e:
        raise _write_error(path, e) from None
    os.close(fd)
    return Path(tmp)


def _write_bytes(path: Path, data: bytes) -> None:
    with open(path, "wb") as fh:
        fh.write(data)


def _link_new(tmp: Path, final: Path) -> None:
    """Give ``tmp`` the name ``final`` only if nothing has that name (FileExistsError otherwise)."""
    try:
        os.link(tmp, final)
    except FileExistsError:
        raise
    except OSError as e:
        if e.errno not in _NO_HARD_LINKS:
            raise
        # a file system without hard links (FAT, some FUSE): claim the name exclusively,
        # then rename over our own claim
        os.close(os.open(final, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666 & ~_UMASK))
        os.replace(tmp, final)
    else:
        os.unlink(tmp)


def _commit(pairs, *, overwrite: bool, inputs=()) -> None:
    """Move every (tmp, final) pair into place, in order; all or none."""
    done: list[tuple[Path, Path | None]] = []
    final = None
    try:
        for tmp, final in pairs:
            os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600 files
            backup = None
            if overwrite:
                with contextlib.suppress(FileNotFoundError):
                    st = os.stat(final)
                    _check_existing(final, st, inputs)  # a FIFO or an input may have appeared
                if os.path.lexists(final):
                    backup = Path(tempfile.mktemp(prefix=f".{final.stem}.", suffix=".old", dir=final.parent))
                    try:
                        os.link(final, backup, follow_symlinks=False)
                    except OSError:
                        backup = None  # no hard links here: a failed commit cannot restore it
                os.replace(tmp, final)
            else:
                _link_new(tmp, final)
            done.append((final, backup))
    except BaseException as e:
        for f, backup in reversed(done):
            with contextlib.suppress(OSError):
                if backup is not None:
                    os.replace(backup, f)
                else:
                    os.unlink(f)
        if isinstance(e, FacetexError):  # already one line naming the file (OutputError is an OSError)
            raise
        if isinstance(e, FileExistsError):
            raise OutputError(_APPEARED, path=final) from None
        if isinstance(e, OSError):
            raise _write_error(final, e) from None
        raise
    for f, backup in done:
        if backup is not None:
            with contextlib.suppress(OSError):
                os.unlink(backup)
    with _COMMITTED_LOCK:
        _COMMITTED.extend(f for f, _ in done)
        _SEEN_ABSENT.difference_update(os.path.abspath(f) for f, _ in done)  # ours now: "exists" next time


def write_files(items, *, overwrite: bool = False, inputs=(), reverse_commit: bool = False) -> list[Path]:
    """Write several outputs as one: ``items`` maps each path to its content (bytes, str,
    or a callable writing the given temporary path). All paths are checked
    (:func:`check_output_path`), all contents written to temporary files beside them, then
    all committed (exclusive create unless ``overwrite``); on any failure nothing new is
    left and nothing replaced. Returns the paths. ``reverse_commit``: move the files into
    place last written first (a sidecar written after its output but committed before it, so
    that a process killed mid-commit leaves the sidecar, never an output without one)."""
    items = list(items.items()) if isinstance(items, dict) else list(items)
    paths = check_outputs([p for p, _ in items], overwrite=overwrite, inputs=inputs)
    temps: list[Path] = []
    try:
        for path, (_, content) in zip(paths, items):
            tmp = _temp_beside(path)
            temps.append(tmp)
            try:
                if callable(content):
                    content(tmp)
                else:
                    _write_bytes(tmp, content.encode("utf-8") if isinstance(content, str) else bytes(content))
            except FacetexError:
                raise
            except OSError as e:
                raise _write_error(path, e) from None
        pairs = list(zip(temps, paths))
        _commit(pairs[::-1] if reverse_commit else pairs, overwrite=overwrite, inputs=inputs)
    finally:
        for t in temps:
            with contextlib.suppress(OSError):
                t.unlink()
    return paths


@contextlib.contextmanager
def atomic_path(path, *, overwrite: bool = True, inputs=()) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same extension); on success move it to
    ``path`` (os.replace with ``overwrite``, else an exclusive create that fails if ``path``
    exists); delete it on any exception (KeyboardInterrupt too). OSErrors become OutputError."""
    path = Path(path)
    tmp = _temp_beside(path)
    try:
        try:
            yield tmp
        except FacetexError:
            raise
        except OSError as e:
            raise _write_error(path, e) from None
        _commit([(tmp, path)], overwrite=overwrite, inputs=inputs)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()


def encode_image(path, image: np.ndarray, *, quality: int = 95, bit_depth: int = 8) -> bytes:
    """The bytes of ``image`` encoded in the format of ``path``'s extension (see :func:`write_image`)."""
    path = Path(path)
    fmt = IMAGE_EXTENSIONS.get(path.suffix.lower())
    if fmt is None:
        raise OutputError(f"unknown image extension {path.suffix or '(none)'!r}: use one of "
                          f"{', '.join(sorted(IMAGE_EXTENSIONS))}", path=path)
    if bit_depth not in (8, 16) or (bit_depth == 16 and fmt not in ("png", "tiff")):
        raise BadInputError(f"bit_depth {bit_depth} not possible for {fmt}: use 8, or 16 with .png/.tif",
                            path=path)
    img = np.asarray(image)
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (1, 3, 4)) or img.size == 0:
        raise BadInputError(f"cannot write image of shape {img.shape}: need (H,W), (H,W,3) or (H,W,4)",
                            path=path)
    if np.issubdtype(img.dtype, np.floating):  # processing may overshoot [0, 1] a little: clipped
        check_float_pixels(img, "the image to write", slack=0.5, path=path)
    if bit_depth == 16:
        img = img if img.dtype == np.uint16 else np.clip(np.rint(to_float32(img) * 65535), 0, 65535
                                                         ).astype(np.uint16)
    else:
        img = to_uint8(img)
    if img.ndim == 3 and img.shape[2] >= 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR if img.shape[2] == 3 else cv2.COLOR_RGBA2BGRA)
    params = {"jpeg": [cv2.IMWRITE_JPEG_QUALITY, int(quality)],
              "webp": [cv2.IMWRITE_WEBP_QUALITY, int(quality)]}.get(fmt, [])
    ok, buf = cv2.imencode(path.suffix.lower(), img, params)
    if not ok:
        raise OutputError(f"OpenCV could not encode {fmt}", path=path)
    return buf.tobytes()


def write_image(path, image: np.ndarray, *, overwrite: bool = True, quality: int = 95,
                bit_depth: int = 8, inputs=()) -> Path:
    """Write float [0, 1] / uint8 / uint16 RGB (or gray 2-D, or RGBA) atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The output; its extension sets the format (.png .jpg .jpeg .tif .tiff .webp).
    image : numpy.ndarray
        (H, W, 3), (H, W) or (H, W, 4); float in [0, 1], uint8 or uint16.
    overwrite : bool
        False: an existing file (also one that appears while encoding) is never replaced.
    quality : int
        JPEG and WebP quality.
    bit_depth : {8, 16}
        16 writes 16-bit PNG/TIFF.
    inputs : sequence of path
        Files the output must not be (see :func:`check_output_path`).

    Returns
    -------
    pathlib.Path
        The written file.

    Raises
    ------
    facetex.OutputError
        The output cannot be written, exists without ``overwrite``, or is one of ``inputs``.
    facetex.BadImageError
        A float image with NaN or infinite values, or far outside [0, 1] (a 0..255 image:
        divide by 255); overshoots of up to 0.5 are clipped. Nothing is written.
    """
    path = check_output_path(path, overwrite=overwrite, inputs=inputs, extensions=IMAGE_EXTENSIONS,
                             what="image")
    return write_files({path: encode_image(path, image, quality=quality, bit_depth=bit_depth)},
                       overwrite=overwrite, inputs=inputs)[0]


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


def encode_json(obj) -> bytes:
    """``obj`` as indented UTF-8 JSON (numpy scalars/arrays, paths, dataclasses converted)."""
    return (json.dumps(obj, indent=2, default=_json_default) + "\n").encode("utf-8")


def write_json(path, obj, *, overwrite: bool = True, inputs=()) -> Path:
    """Write ``obj`` as indented JSON atomically (numpy scalars/arrays, paths, dataclasses converted)."""
    path = check_output_path(path, overwrite=overwrite, inputs=inputs)
    return write_files({path: encode_json(obj)}, overwrite=overwrite, inputs=inputs)[0]


# ------------------------------------------------------------------------------- npz
def read_npy_header(fh) -> tuple[tuple[int, ...], bool, np.dtype]:
    """(shape, fortran order, dtype) of the .npy header at ``fh``'s position (left just after
    it); a header over 10 kB is refused (numpy's ValueError)."""
    version = np.lib.format.read_magic(fh)
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, fortran, dtype = read(fh, max_header_size=10_000)
    return tuple(int(s) for s in shape), bool(fortran), dtype


def npz_members(path, error: type = BadInputError, *, what: str = "file") -> dict[str, dict]:
    """What every member of an ``.npz`` (zip) declares, read from the zip directory and the
    first bytes of each ``.npy`` member (nothing else is decompressed): name (without
    ``.npy``) -> {"dtype", "shape", "fortran", "file_size" (uncompressed bytes the zip declares),
    "compress_size"}; dtype/shape are None for a member that is not a .npy array. Raises
    ``error`` naming ``path`` when the zip or a member header is corrupt, or a member holds
    Python objects (pickles are never loaded)."""
    import tokenize
    import zipfile

    path = Path(path)
    out: dict[str, dict] = {}
    try:
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
                rec = {"dtype": None, "shape": None, "fortran": False, "file_size": int(info.file_size),
                       "compress_size": int(info.compress_size)}
                if info.filename.endswith(".npy"):
                    with zf.open(info) as fh:
                        shape, fortran, dtype = read_npy_header(fh)
                    if dtype.hasobject:
                        raise error(f"corrupt {what}: member {name!r} holds Python objects (never loaded)",
                                    path=path)
                    rec.update(dtype=dtype, shape=shape, fortran=fortran)
                out[name] = rec
    except FacetexError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, OSError, EOFError, KeyError, UnicodeDecodeError,
            SyntaxError, tokenize.TokenError, zlib_error, struct_error, RecursionError, OverflowError,
            NotImplementedError, TypeError) as e:
        raise error(f"corrupt {what} ({type(e).__name__}: {_cause(e)})", path=path) from None
    return out


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


def iter_video_frames(path, *, max_frames: int | None = None, uint8: bool = False,
                      max_side: int | None = None) -> Iterator[np.ndarray]:
    """Yield frames as float32 RGB (H, W, 3) in [0, 1] (``uint8``: as decoded, uint8 RGB).
    ``max_side``: frames with a longer side above it are scaled down to it as they are
    converted (area averaging; an 8K frame is never held at full size in RGB).

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
                    if max_side is not None and max(frame.width, frame.height) > max_side:
                        f = max_side / max(frame.width, frame.height)
                        frame = frame.reformat(width=max(2, round(frame.width * f)),
                                               height=max(2, round(frame.height * f)), format="rgb24",
                                               interpolation="AREA")
                    rgb = frame.to_ndarray(format="rgb24")
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


def _encoder_options(codec: str, pixels: int) -> dict:
    if pixels <= ENCODER_FULL_PIXELS or codec != "libx264":
        return {}
    return {"x264-params": "rc-lookahead=5:ref=1:bframes=1"}


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
                overwrite: bool = True, progress: Callable | None = None, inputs=()) -> Path:
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
            vs.options = {"crf": str(int(crf)), **_encoder_options(codec, vs.width * vs.height)}
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
