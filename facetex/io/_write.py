"""Writing images and JSON through the atomic outputs of :mod:`._atomic`."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import cv2
import numpy as np

from ..errors import BadInputError, OutputError
from ._atomic import IMAGE_EXTENSIONS, check_output_path, write_files
from ._convert import check_float_pixels, to_float32, to_uint8


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
