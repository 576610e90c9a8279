"""Reading images: every common format as float32 RGB in [0, 1] (EXIF orientation, 16-bit,
CMYK, alpha, decompression bombs refused from the header), and the public functions' image
arguments (:data:`ImageLike`, :func:`as_image`, :func:`image_args`)."""

from __future__ import annotations

import contextlib
import math
import os
import threading
import warnings
from io import BytesIO
from pathlib import Path
from struct import error as struct_error
from typing import TYPE_CHECKING, Callable, TypeVar, Union
from zlib import error as zlib_error

import cv2
import numpy as np
from PIL import Image, ImageCms, ImageOps, UnidentifiedImageError

from ..errors import BadImageError, BadInputError
from ._convert import check_float_pixels, to_float32, to_uint8
from ._files import _cause, check_input_file

if TYPE_CHECKING:
    from PIL.Image import Image as PILImage

_BACKGROUNDS = {"white": 1.0, "black": 0.0}
_PIL_LIMIT_LOCK = threading.Lock()  # guards our brief change of Pillow's global pixel limit
_ALPHA_MODES = {"RGBA", "LA", "PA", "RGBa", "La"}


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
