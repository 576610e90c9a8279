"""Per-channel pixel helpers of the compositing (numpy broadcasts over a length-3 inner axis and
gathers (H, W, 3) pixels by a bool mask several times slower than the same arithmetic one channel
at a time / np.take on flat indices)."""

from __future__ import annotations

import numpy as np

_LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)  # linear-light luminance (Rec. 709)


def _shape2(shape) -> tuple[int, int]:
    h, w = (int(v) for v in shape[:2])
    return h, w


# numpy broadcasts over a length-3 inner axis (an (H, W) weight or a (3,) colour against an
# (H, W, 3) image) and gathers (H, W, 3) pixels by a bool mask several times slower than the same
# arithmetic one channel at a time / np.take on flat indices: the helpers below do that
def _mix(alpha, a, b) -> np.ndarray:
    """alpha * a + (1 - alpha) * b of (H, W) ``alpha`` and (H, W, 3) float32 images."""
    out = np.empty(np.shape(a), np.float32)
    beta = 1 - alpha
    for c in range(3):
        out[..., c] = alpha * a[..., c] + beta * b[..., c]
    return out


def _pixels(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """img[mask] (N, 3) of an (H, W, 3) image and an (H, W) bool mask."""
    return np.ascontiguousarray(img).reshape(-1, 3).take(np.flatnonzero(mask), axis=0)


def _shift(img: np.ndarray, by) -> np.ndarray:
    """img + by of an (H, W, 3) float32 image and a (3,) colour."""
    out = np.empty(img.shape, np.float32)
    for c in range(3):
        np.add(img[..., c], by[c], out=out[..., c])
    return out


