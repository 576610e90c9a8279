"""Skin marks — moles, spots, scars' dots — as dark blobs on the skin's luminance (issue 22).

A mark is a local minimum of the luminance relative to its surroundings at the scale of a
few pixels: the *darkness* ``d = max(0, L_m − L)`` (``L_m``: the skin's luminance low-passed
over the skin only, so brows and hair never count as surroundings) is searched with a
Laplacian-of-Gaussian blob detector (:func:`skimage.feature.blob_log`, scale-normalised,
Lindeberg 1998) between ``min_sigma`` and ``max_sigma``. Pores (σ ≲ 1 px on a 1000 px
portrait) and shading (σ ≳ 10 px) fall outside that range; ``threshold`` is the LoG response
(luminance 0..1) a blob must reach. Lengths are given at a 330 px face width and scaled with
the face. Pure numpy / scikit-image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import BadInputError
from ..io import LUMA_BT601
from .filters import masked_lowpass

__all__ = ["MarkParams", "detect_marks", "marks_mask", "match_marks", "REF_FACE_WIDTH"]

REF_FACE_WIDTH = 330.0  # px, |p16 − p0| on a 1000 px FRL portrait


@dataclass(frozen=True)
class MarkParams:
    """Blob search of :func:`detect_marks` (lengths in px at REF_FACE_WIDTH)."""

    min_sigma: float = 1.5  # a 4 px mole; pores are smaller
    max_sigma: float = 5.0  # a 14 px mole; larger dark areas are shading or hair
    num_sigma: int = 5
    threshold: float = 0.03  # LoG response (luminance 0..1, scale-normalised) a mark must reach
    background: float = 12.0  # σ of the skin-only low-pass that is the marks' surroundings
    min_skin: float = 0.5  # a mark's centre lies where the skin mask is at least this


def _luma(image) -> np.ndarray:
    a = np.asarray(image, np.float32)
    if a.ndim == 3:
        a = a[..., :3] @ LUMA_BT601
    return a


def detect_marks(image, skin, *, face_width: float = REF_FACE_WIDTH, params: MarkParams = MarkParams()) -> np.ndarray:
    """Dark blobs on the skin: float (N, 3) array of (x, y, radius) in pixels of ``image``.

    ``image``: (H, W, 3) or (H, W) in [0, 1]; ``skin``: (H, W) mask in [0, 1] (blobs whose
    centre has ``skin`` < ``min_skin`` are dropped; only the skin is searched, within its
    bounding box); ``face_width`` scales the lengths of ``params``. Radius = √2 σ."""
    from skimage.feature import blob_log

    lum = _luma(image)
    m = np.clip(np.asarray(skin, np.float32), 0, 1)
    if m.shape != lum.shape:
        raise BadInputError(f"skin mask has shape {m.shape}, the image {lum.shape}")
    scale = float(face_width) / REF_FACE_WIDTH
    if not scale > 0:
        raise BadInputError(f"face_width must be > 0, got {face_width}")
    ys, xs = np.nonzero(m >= params.min_skin)
    if ys.size == 0:
        return np.zeros((0, 3))
    pad = int(np.ceil(3 * params.background * scale))
    y0, y1 = max(0, ys.min() - pad), min(lum.shape[0], ys.max() + pad + 1)
    x0, x1 = max(0, xs.min() - pad), min(lum.shape[1], xs.max() + pad + 1)
    lum, m = lum[y0:y1, x0:x1], m[y0:y1, x0:x1]
    surround = masked_lowpass(lum, m, params.background * scale)
    dark = np.clip(surround - lum, 0.0, None) * (m > 0.05)
    blobs = blob_log(dark, min_sigma=params.min_sigma * scale, max_sigma=params.max_sigma * scale,
                     num_sigma=params.num_sigma, threshold=params.threshold, exclude_border=False)
    if len(blobs) == 0:
        return np.zeros((0, 3))
    yy, xx = blobs[:, 0].astype(int), blobs[:, 1].astype(int)
    keep = m[yy, xx] >= params.min_skin
    b = blobs[keep]
    return np.column_stack([b[:, 1] + x0, b[:, 0] + y0, b[:, 2] * np.sqrt(2.0)]).astype(np.float64)


def marks_mask(marks, shape, *, grow: float = 2.0) -> np.ndarray:
    """float32 (H, W) in [0, 1]: discs of ``grow`` × each mark's radius, feathered over half
    the radius (1 at a mark's centre, 0 beyond the disc's soft edge)."""
    h, w = shape[:2]
    out = np.zeros((h, w), np.float32)
    for x, y, r in np.asarray(marks, np.float64).reshape(-1, 3):
        rr = max(1.0, grow * r)
        half = max(0.5, 0.5 * r)
        x0, x1 = int(max(0, np.floor(x - rr - 2 * half))), int(min(w, np.ceil(x + rr + 2 * half) + 1))
        y0, y1 = int(max(0, np.floor(y - rr - 2 * half))), int(min(h, np.ceil(y + rr + 2 * half) + 1))
        if x1 <= x0 or y1 <= y0:
            continue
        gy, gx = np.mgrid[y0:y1, x0:x1]
        dist = np.hypot(gx - x, gy - y)
        disc = np.clip((rr + half - dist) / (2 * half), 0.0, 1.0)  # linear ramp across the edge
        out[y0:y1, x0:x1] = np.maximum(out[y0:y1, x0:x1], disc)
    return out


def match_marks(a, b, *, tolerance: float = 1.5) -> np.ndarray:
    """bool (len(a),): whether each mark of ``a`` has a mark of ``b`` within
    ``tolerance`` × the larger of the two radii (at least 2 px)."""
    a = np.asarray(a, np.float64).reshape(-1, 3)
    b = np.asarray(b, np.float64).reshape(-1, 3)
    if len(a) == 0 or len(b) == 0:
        return np.zeros(len(a), bool)
    d = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1])
    reach = np.maximum(tolerance * np.maximum(a[:, None, 2], b[None, :, 2]), 2.0)
    return (d <= reach).any(1)
