"""The gradient-domain composite of :func:`~facetex.puppet.composite.composite_face`'s optional
Poisson step (Pérez et al. 2003): :func:`poisson_blend`."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import BadInputError

__all__ = ["poisson_blend", "GUIDE_ERODE"]

#: erosion (3 x 3 steps) of the mask inside which the source's gradients guide the blend: OpenCV's
#: ``seamlessClone`` uses 3, and the pixels next to the border follow the destination's gradients
GUIDE_ERODE = 3


def _dst1_eigenvalues(n: int) -> np.ndarray:
    """(n - 2,) eigenvalues 2 cos(pi k / (n - 1)) - 2, k = 1..n-2, of the 1-D second difference with
    zero Dirichlet ends on n samples (the DST-I diagonalizes it)."""
    return 2 * np.cos(np.pi * np.arange(1, n - 1) / (n - 1)) - 2


def poisson_blend(src, dst, mask, *, erode: int = GUIDE_ERODE) -> np.ndarray:
    """Gradient-domain composite (Pérez et al. 2003, "normal clone"): inside the bool ``mask``
    the result has ``src``'s gradients and agrees with ``dst`` on the mask's border; outside it
    is ``dst``. ``src``, ``dst`` (H, W, 3) float [0, 1] of the same size, aligned.

    The guidance field of OpenCV's ``seamlessClone`` solved in float32: on the mask's bounding box
    R, f = dst + u with Δu = div(m ∇(src − dst)) (forward differences, m the mask eroded by
    ``erode`` px, so the pixels next to the border follow ``dst``'s own gradients) and u = 0 on R's
    border, solved exactly by the discrete sine transform (scipy.fft, DST-I) as OpenCV does; the
    same f as its 8-bit solve (which rounds the inputs and truncates the result: a one-ulp change
    of ``src`` could move it by 1.4/255), without the quantization."""
    import scipy.fft

    s = np.asarray(src, np.float32)
    d = np.asarray(dst, np.float32)
    m = np.asarray(mask, bool)
    if s.shape != d.shape or m.shape != s.shape[:2] or s.ndim != 3:
        raise BadInputError(f"src {s.shape}, dst {d.shape} and mask {m.shape} must have the same size")
    out = d.copy()
    if m.sum() < 4:
        return out
    x0, y0, bw, bh = cv2.boundingRect(m.view(np.uint8))
    if bw < 3 or bh < 3:
        return out
    box = (slice(y0, y0 + bh), slice(x0, x0 + bw))
    mc = m[box]
    # the erosion sees nothing outside the box (as OpenCV's on the mask's bounding-box view)
    guide = cv2.erode(mc.view(np.uint8), np.ones((3, 3), np.uint8), iterations=max(0, int(erode)),
                      borderType=cv2.BORDER_CONSTANT, borderValue=0) if erode > 0 else mc.view(np.uint8)
    guide = guide.astype(np.float32)[..., None]
    diff = s[box] - d[box]
    gx = np.zeros_like(diff)
    gy = np.zeros_like(diff)
    np.subtract(diff[:, 1:], diff[:, :-1], out=gx[:, :-1])
    np.subtract(diff[1:], diff[:-1], out=gy[:-1])
    gx *= guide
    gy *= guide
    # divergence (backward differences) at the interior pixels; u = 0 on the box's border
    div = gx[1:-1, 1:-1] - gx[1:-1, :-2]
    div += gy[1:-1, 1:-1]
    div -= gy[:-2, 1:-1]
    coef = scipy.fft.dstn(div, type=1, axes=(0, 1))
    coef /= (_dst1_eigenvalues(bh)[:, None] + _dst1_eigenvalues(bw)[None, :]).astype(np.float32)[..., None]
    f = d[box].copy()
    f[1:-1, 1:-1] += scipy.fft.idstn(coef, type=1, axes=(0, 1))
    np.clip(f, 0, 1, out=f)
    out[box] = np.where(mc[..., None], f, d[box])
    return out
