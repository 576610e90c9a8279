"""Pixel conversions: integer and float images, and the check of float pixels."""

from __future__ import annotations

import numpy as np

from ..errors import BadImageError

#: ITU-R BT.601 luma weights of (R, G, B), float32: ``img @ LUMA_BT601`` is the gray level every
#: module that reads brightness from sRGB pixels uses (Rec. 709 linear-light luminance is
#: ``facetex.puppet._pixels``' own)
LUMA_BT601 = np.array([0.299, 0.587, 0.114], np.float32)


def srgb_to_linear(x):
    """sRGB-encoded [0, 1] -> linear light (IEC 61966-2-1)."""
    x = np.asarray(x, np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((np.maximum(x, 0.04045) + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(x):
    """Linear light -> sRGB-encoded [0, 1] (clipped)."""
    x = np.clip(np.asarray(x, np.float32), 0, 1)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.maximum(x, 0.0031308) ** (1 / 2.4) - 0.055).astype(np.float32)


def to_float32(img: np.ndarray) -> np.ndarray:
    """uint8 / uint16 / float image -> float32 in [0, 1] (integers scaled by their max)."""
    img = np.asarray(img)
    if img.dtype in (np.uint8, np.uint16):
        a = img.astype(np.float32)
        a /= 255.0 if img.dtype == np.uint8 else 65535.0  # in place: one float copy, not two
        return a
    return img.astype(np.float32, copy=False)


_STRIP = 1 << 22  # values per row strip of a large image


def _row_strips(a: np.ndarray) -> list:
    """Indices of row strips of ``a`` of about :data:`_STRIP` values each; ``...`` (all of it)
    for a small (or 0-d) array."""
    if a.ndim == 0 or a.size <= _STRIP:
        return [...]
    rows = max(1, _STRIP // (a.size // a.shape[0]))
    return [slice(i, i + rows) for i in range(0, a.shape[0], rows)]


def _all_finite(a: np.ndarray) -> bool:
    """Whether every value of ``a`` is finite; a large array in row strips (no boolean
    temporary of its size: a 6000 x 6000 float64 image would need 108 MB)."""
    return all(bool(np.all(np.isfinite(a[r]))) for r in _row_strips(a))


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
    out = np.empty(a.shape, np.uint8)  # a 36 MP image in strips: no float temporaries of its size
    for r in _row_strips(a):
        out[r] = np.clip(np.rint(a[r] * 255.0), 0, 255)
    return out
