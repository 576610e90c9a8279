"""Occluders in a persona's photos: hands, hair, microphones or a towel over the face.

A photo collection holds a few photos with a hand over the mouth and cheek, hair over a temple or a
microphone at the chin. The blend takes each pixel from the photos whose expression is nearest the
target's, so a 52-photo persona whose closed-mouth photos included two with a hand over the mouth
drew the fingers as streaks across the puppet's cheek on every frame of a talking driver. The
robust product (``TextureParams.robust``) catches such a photo only where it disagrees with the
other photos of that target's blend, and costs a frame ~7 ms more per region it covers.

Here each photo is judged once, against the photos with the nearest expressions (the 49 normalised
fiducials, :func:`facetex.persona.weights.normalised_fiducials`): per pixel, how far its fine
structure (a band-pass of its luminance, in units of that photo's own median band amplitude, so
harsh or soft light count alike) departs from the per-pixel median of its neighbours'. Structure
that its neighbours share (the creases of the same smile) is not an occluder; fingers, hair
strands and the edges of a microphone are. The departure is blurred, measured in units of the
collection's median departure at that pixel (the nose's and the jaw's edges depart more in every
photo than a flat cheek) and turned into a factor 1 / (1 + max(0, d / s - kappa)^2), grown by
:data:`GROW` px (a hand's flat back departs little; its fingers' edges do) and floored. The mouth,
the eyes and the brows are not judged: their structure is the expression, and the robust product
and the expression weights look after them. Written by hand: no library judges an image against
its neighbours in an expression space.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..geometry.frontalize import CANONICAL_SIZE

__all__ = ["band_structure", "occlusion_factors", "judged_region", "occlude_aligned"]

#: Gaussian sigmas (px at the 192 px wide canonical frame) of the band-pass: fingers' and hair's
#: edges, not the lighting
BAND = (1.0, 4.0)
#: photos with the nearest expressions a photo is judged against
NEIGHBOURS = 8
#: blur (px) of a photo's departure before it is judged, and the erosion radius (px) that grows
#: what is judged an occluder over the rest of it
BLUR = 3.0
GROW = 6
#: photos (evenly spread) whose departures give the collection's median at a pixel
SCALE_PHOTOS = 64
#: the smallest factor: an occluded pixel still counts a little (a collection where one photo alone
#: sees a pixel keeps it)
FLOOR = 0.05


def _px(width: int) -> float:
    """Pixels of a ``width`` px wide frame per pixel of the 192 px canonical frame."""
    return width / float(CANONICAL_SIZE[0])


def band_structure(image: np.ndarray) -> np.ndarray:
    """(H, W) float32 band-pass (difference of Gaussians, :data:`BAND`) of an (H, W, 3) RGB
    image's luminance in [0, 1]."""
    g = cv2.cvtColor(np.ascontiguousarray(image, np.float32), cv2.COLOR_RGB2GRAY)
    s = _px(g.shape[1])
    return cv2.GaussianBlur(g, (0, 0), BAND[0] * s) - cv2.GaussianBlur(g, (0, 0), BAND[1] * s)


def judged_region(points68, shape, face: np.ndarray) -> np.ndarray:
    """(H, W) float32 in [0, 1]: where occluders are judged, the soft ``face`` region without the
    lips, eyes and brows of the (mean) landmarks ``points68`` (:func:`facetex.geometry.masks.feature_mask`
    grown 0.1 of the outer eye-corner distance, feathered)."""
    from ..geometry.masks import feature_mask
    from ..landmarks import eye_distance

    p = np.asarray(points68, np.float64)
    feats = feature_mask(p, shape, dilate=0.1).astype(np.float32)  # x the outer eye-corner distance
    feats = cv2.GaussianBlur(feats, (0, 0), max(0.05 * eye_distance(p), 0.5))
    return np.clip(np.asarray(face, np.float32) * (1.0 - np.clip(2 * feats, 0, 1)), 0, 1).astype(np.float32)


def occlusion_factors(bands: np.ndarray, sure: np.ndarray, coords: np.ndarray, judged: np.ndarray, *,
                      kappa: float, neighbours: int = NEIGHBOURS) -> np.ndarray:
    """(n, H, W) float32 factors in [:data:`FLOOR`, 1] of each photo's pixel confidence (module doc).

    ``bands``: (n, H, W) :func:`band_structure` of the photos aligned to one frame; ``sure``: (n, H, W)
    bool, the pixels each photo saw itself; ``coords``: (n, D) expression coordinates (the nearest
    ``neighbours`` photos are a photo's reference); ``judged``: (H, W) in [0, 1], where to judge
    (:func:`judged_region`; 0 leaves a pixel's factor 1); ``kappa``: departures up to kappa times
    the collection's median at a pixel are not occluders."""
    from scipy.spatial.distance import cdist

    b = np.array(bands, np.float32)  # a copy: scaled in place
    n, H, W = b.shape
    judged = np.asarray(judged, np.float32)
    out = np.ones((n, H, W), np.float32)
    if n < 3 or not kappa > 0:
        return out
    area = judged > 0.5
    for i in range(n):
        px = np.abs(b[i][area & sure[i]])
        if px.size == 0:
            px = np.abs(b[i][area]) if area.any() else np.ones(1, np.float32)
        b[i] *= np.float32(1.0 / max(float(np.median(px)), 1e-6))
    c = np.asarray(coords, np.float64).reshape(n, -1)
    d = cdist(c, c)
    np.fill_diagonal(d, np.inf)
    k = int(min(max(1, neighbours), n - 1))
    near = np.argsort(d, axis=1, kind="stable")[:, :k]
    px = _px(W)
    dep = np.empty((n, H, W), np.float32)
    for i in range(n):
        x = b[near[i]]
        x.sort(axis=0)  # the median of the neighbours, as np.median gives it (3x faster on (8, H, W))
        ref = x[k // 2] if k % 2 else (x[k // 2 - 1] + x[k // 2]) * np.float32(0.5)
        np.subtract(b[i], ref, out=ref)
        dep[i] = cv2.GaussianBlur(np.abs(ref, out=ref), (0, 0), BLUR * px)
    # the collection's median departure per pixel over the photos that saw it (at most
    # SCALE_PHOTOS of them, evenly spread: a smooth statistic), smoothed
    pick = np.unique(np.linspace(0, n - 1, min(n, SCALE_PHOTOS)).round().astype(int))
    masked = np.where(sure[pick], dep[pick], np.float32(np.nan))
    counted = np.isfinite(masked).any(axis=0)
    s = np.full((H, W), np.nan, np.float32)
    if counted.any():
        s[counted] = np.nanmedian(masked[:, counted], axis=0)
    s = np.where(np.isfinite(s), s, np.nanmedian(s) if np.isfinite(s).any() else 1.0).astype(np.float32)
    inv = np.float32(1.0) / np.maximum(cv2.GaussianBlur(s, (0, 0), 2 * BLUR * px), np.float32(1e-6))
    r = max(1, int(round(GROW * px)))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    for i in range(n):
        e = np.maximum(dep[i] * inv - np.float32(kappa), np.float32(0.0))
        f = np.float32(1.0) / (np.float32(1.0) + e * e)
        g = cv2.GaussianBlur(cv2.erode(f, kernel), (0, 0), r / 2)
        out[i] = np.maximum(np.float32(1.0) - (np.float32(1.0) - g) * judged, np.float32(FLOOR))
    return out


def occlude_aligned(codes: np.ndarray, lsb: np.ndarray, luts: tuple, fiducials, points68, conf_range: tuple,
                    kappa: float) -> np.ndarray:
    """Scale the confidences of a persona's aligned photos (the (n, H, W, 4) uint8 codes and 9th bits
    of :func:`facetex.persona._stack_store._quantize_aligned`, ``luts`` to read them) by their
    occluders' factors, in place; returns the (n, H, W) factors. Judged against the photos with the
    nearest expressions (all 49 normalised ``fiducials``), inside the face of the mean
    ``points68`` without its features (:func:`judged_region`)."""
    from ..geometry.masks import face_mask
    from ._stack_store import _dequantize_aligned
    from .weights import normalised_fiducials

    n, H, W = codes.shape[:3]
    bands = np.empty((n, H, W), np.float32)
    sure = np.empty((n, H, W), bool)
    work: dict = {}
    for i in range(n):
        ic = _dequantize_aligned(codes[i], lsb[i], luts, work)
        bands[i] = band_structure(ic[..., :3])
        sure[i] = ic[..., 3] >= 0.5  # seen by the photo itself, inside its face
    f = np.asarray(fiducials, np.float64)
    coords = normalised_fiducials(f, f.mean(axis=0)).reshape(n, -1)
    factors = occlusion_factors(bands, sure, coords, judged_region(points68, (H, W), face_mask(points68, (H, W))),
                                kappa=kappa)
    # the codes are 255 log(c / lo) / log(hi / lo): c x f adds 255 log(f) / log(hi / lo)
    lo, hi = conf_range
    c = codes[..., 3].astype(np.float32) + np.float32(255 / np.log(hi / lo)) * np.log(factors)
    codes[..., 3] = np.clip(np.rint(c), 0, 255).astype(np.uint8)
    return factors
