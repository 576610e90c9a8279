"""Laplacian pyramids and their Eq. 3 blend (Tom Hanks §5): the expression similarity, the per-level
weights with the uniform term, the blend and collapse (see :mod:`facetex.persona.texture` for the
level indexing)."""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = [
    "pyramid_levels",
    "gaussian_pyramid",
    "laplacian_pyramid",
    "collapse_pyramid",
    "laplacian_response",
    "expression_similarity",
    "eq3_weights",
    "blend_pyramids",
]


# ------------------------------------------------------------------ pyramids, Eq. 3
def pyramid_levels(shape, min_side: int = 8) -> int:
    """Number of levels p so the coarsest level's smaller side is about ``min_side`` px."""
    s = min(int(shape[0]), int(shape[1]))
    return max(1, int(math.floor(math.log2(max(s, 1) / min_side))) + 1)


def gaussian_pyramid(image: np.ndarray, levels: int) -> list[np.ndarray]:
    """Gaussian pyramid (cv2.pyrDown), finest (the image as float32) first."""
    g = [np.asarray(image, np.float32)]
    for _ in range(levels - 1):
        g.append(cv2.pyrDown(g[-1]))
    return g


def laplacian_pyramid(image: np.ndarray, levels: int) -> list[np.ndarray]:
    """Laplacian pyramid (cv2.pyrDown / pyrUp), finest band first, Gaussian residual last."""
    g = gaussian_pyramid(image, levels)
    pyr = [g[k] - cv2.pyrUp(g[k + 1], dstsize=(g[k].shape[1], g[k].shape[0])) for k in range(levels - 1)]
    pyr.append(g[-1])
    return pyr


def collapse_pyramid(pyr: list[np.ndarray]) -> np.ndarray:
    """Inverse of :func:`laplacian_pyramid` (exact up to float rounding)."""
    img = pyr[-1]
    for band in reversed(pyr[:-1]):
        img = band + cv2.pyrUp(img, dstsize=(band.shape[1], band.shape[0]))
    return img


def laplacian_response(gaussian_level: np.ndarray, *, blur: float = 1.0, floor: float = 1e-3) -> np.ndarray:
    """L of Eq. 3 on one pyramid level: blurred |Laplacian| of the luminance, plus a floor."""
    g = gaussian_level
    if g.ndim == 3:
        g = cv2.cvtColor(np.ascontiguousarray(g, np.float32), cv2.COLOR_RGB2GRAY)
    L = np.abs(cv2.Laplacian(g.astype(np.float32), cv2.CV_32F, ksize=3))
    if blur > 0:
        L = cv2.GaussianBlur(L, (0, 0), blur)
    return L + np.float32(floor)


def expression_similarity(target, fiducials, sigma: float = 10.0, *, scale: float = 1.0) -> np.ndarray:
    """exp(-||F^T - F^i||^2 / 2 sigma^2) per photo (n,), float64; distances times ``scale``."""
    t = np.asarray(target, np.float64)
    f = np.asarray(fiducials, np.float64)
    d2 = ((f - t) ** 2).sum(axis=(-2, -1)) * scale**2
    return np.exp(-d2 / (2.0 * sigma**2))


def _uniform_term(level: int, tau: float, beta: float) -> float:
    return math.inf if level == 0 else tau * float(level) ** (-beta)


def eq3_weights(similarity, laplacian, level: int, *, tau: float = 1.0, beta: float = 20.0,
                alpha: float = 1.0) -> np.ndarray:
    """Unnormalised W^i_jk = (similarity_i + tau l^-beta) (L^i_jk)^alpha  # Eq. 3 (Tom Hanks)

    ``similarity`` (n,), ``laplacian`` (n, ...); ``level`` l with 0 the coarsest. At l = 0
    the uniform term is infinite: returned are its normalisation-equivalent limit L^alpha."""
    s = np.asarray(similarity, np.float64)
    L = np.asarray(laplacian, np.float64) ** alpha
    u = _uniform_term(level, tau, beta)
    a = np.ones_like(s) if math.isinf(u) else s + u
    return a.reshape((-1,) + (1,) * (L.ndim - 1)) * L


#: Outside the face support the finest OUTSIDE_SMOOTH_LEVELS pyramid bands are left out: there
#: (hair, neck, collar, background) every frontalized photo is stretched along the generic
#: surface's steep extension, and the average keeps the streaks it paints.
OUTSIDE_SMOOTH_LEVELS = 2

#: fraction of a target's total expression similarity that the fine pyramid levels sum over
#: exactly (the photos with the smallest similarities that make up the rest are left out)
SPARSE_MASS = 0.995


def _cut_small(similarity: np.ndarray, mass: float = SPARSE_MASS, max_photos: int | None = None) -> np.ndarray:
    """(B, n) similarities with each target's smallest ones that together hold less than
    1 - ``mass`` of its total set to 0, and all but the ``max_photos`` largest."""
    S = np.array(np.atleast_2d(similarity), np.float64)
    if max_photos is not None and max_photos < S.shape[-1]:
        kth = -np.partition(-S, max_photos - 1, axis=-1)[:, max_photos - 1 : max_photos]
        S = np.where(S >= kth, S, 0.0)
    if mass >= 1.0:
        return S
    order = np.argsort(S, axis=-1)  # ascending
    srt = np.take_along_axis(S, order, axis=-1)
    cum = np.cumsum(srt, axis=-1)
    drop = cum < (1.0 - mass) * cum[:, -1:]
    np.put_along_axis(S, order, np.where(drop, 0.0, srt), axis=-1)
    return S


def _level_scalars(similarity: np.ndarray, level: int, tau: float, beta: float) -> np.ndarray:
    """Per-photo factor of Eq. 3 at ``level`` ((n,) or (B, n) for B targets), divided by its
    maximum per target (the normalisation of the weights cancels it; this keeps float32
    away from underflow)."""
    u = _uniform_term(level, tau, beta)
    if math.isinf(u):
        return np.ones(np.shape(similarity), np.float32)
    a = similarity + u
    return (a / np.maximum(a.max(axis=-1, keepdims=True), 1e-300)).astype(np.float32)


def blend_pyramids(pyramids: list[list[np.ndarray]], weights: list[list[np.ndarray]]) -> np.ndarray:
    """Collapse of the per-level weighted average (normalised per pixel) of Laplacian pyramids.

    ``pyramids[i][k]``: level k (finest first) of photo i; ``weights[i][k]``: (h_k, w_k) weights."""
    out = []
    for k in range(len(pyramids[0])):
        num = sum(w[k][..., None] * p[k] for p, w in zip(pyramids, weights))
        den = sum(w[k] for w in weights)[..., None]
        out.append(num / np.maximum(den, 1e-30))
    return collapse_pyramid(out)


