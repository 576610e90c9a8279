"""Pixel helpers of the compositing: the face's box at a working scale (:class:`_Shrunk`), the
skin's weights (:func:`_skin_weights`), and per-channel helpers (numpy broadcasts over a length-3
inner axis and gathers (H, W, 3) pixels by a bool mask several times slower than the same
arithmetic one channel at a time / np.take on flat indices)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
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


@dataclass(frozen=True)
class _Shrunk:
    """The face's box of ``full`` (w, h) px shrunk by the integer ``k`` to ``size`` (w, h): about a
    given number of px between the eye corners (k = 1: as it is)."""

    k: int
    size: tuple[int, int]
    full: tuple[int, int]

    @classmethod
    def of(cls, shape, iod: float, work_iod: float) -> "_Shrunk":
        h, w = shape
        k = max(1, int(iod // work_iod))
        return cls(k, (max(1, round(w / k)), max(1, round(h / k))), (w, h))

    def image(self, x):
        """``x`` (area average, float32) at the shrunk size."""
        return cv2.resize(np.asarray(x, np.float32), self.size, interpolation=cv2.INTER_AREA) if self.k > 1 else x

    def points(self, p):
        """Points ``p`` (box px) in the shrunk box's px (pixel centres kept)."""
        return (p + 0.5) * [self.size[0] / self.full[0], self.size[1] / self.full[1]] - 0.5

    def mask(self, m):
        """bool mask ``m`` at the shrunk size (nearest pixel)."""
        m = np.asarray(m, bool)
        return cv2.resize(m.view(np.uint8), self.size, interpolation=cv2.INTER_NEAREST) > 0 if self.k > 1 else m

    def back(self, x):
        """``x`` at the shrunk size brought back to the box's (bilinear)."""
        return cv2.resize(x, self.full, interpolation=cv2.INTER_LINEAR) if self.k > 1 else x


def _skin_weights(points68, shape) -> np.ndarray:
    """Weight (H, W) float32 in [0, 1] of the skin at iBUG landmarks ``points68``: 1 minus the eyes,
    brows, lips (:func:`~facetex.geometry.masks.feature_mask`) and lower nose
    (:func:`~facetex.geometry.masks.nose_mask`), feathered by 0.04 eye-corner distances: where
    dark detail is shading, not a feature (a lash line, a nostril)."""
    from ..geometry.masks import feature_mask, nose_mask

    p = np.asarray(points68, np.float64)
    m = (feature_mask(p, shape) | nose_mask(p, shape)).astype(np.float32)
    sig = max(0.5, 0.04 * float(np.linalg.norm(p[36] - p[45])))
    return 1.0 - np.clip(cv2.GaussianBlur(m, (0, 0), sig), 0, 1)
