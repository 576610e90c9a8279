"""The puppet's fine detail against the driver's frame: its own detail raised
(:func:`match_sharpness`) and the frame's grain where its own detail is short (:func:`match_grain`)."""

from __future__ import annotations

import math

import cv2
import numpy as np

from ._pixels import _LUMA

__all__ = ["match_sharpness", "match_grain", "GRAIN_CLIP"]

_K4 = np.array([[0, 0.25, 0], [0.25, 0, 0.25], [0, 0.25, 0]], np.float32)
#: the frame's fine band is clipped at this many robust standard deviations of its skin's: the lash
#: lines, glasses rims and creases that survive the feature cut are far stronger than skin grain
GRAIN_CLIP = 2.5


def _high_pass(x: np.ndarray) -> np.ndarray:
    """The pixel-scale band: ``x`` minus the mean of its 4 neighbours (−∇²/4)."""
    return x - cv2.filter2D(x, -1, _K4, borderType=cv2.BORDER_REFLECT)


def _lap(x: np.ndarray) -> np.ndarray:
    return cv2.Laplacian(np.ascontiguousarray(x @ _LUMA), cv2.CV_32F, ksize=1)


def _gain_to_variance(ls: np.ndarray, lh: np.ndarray, target: float) -> float:
    """The k >= 0 with Var(ls + k lh) = ``target`` (a quadratic in k, its larger root; 0 if none):
    ``ls``, ``lh`` Laplacians on the same pixels."""
    ls, lh = ls - ls.mean(), lh - lh.mean()
    a, b = float(np.mean(lh * lh)), 2.0 * float(np.mean(ls * lh))
    c = float(np.mean(ls * ls)) - target
    disc = b * b - 4 * a * c
    return max(0.0, (-b + math.sqrt(disc)) / (2 * a)) if a > 1e-12 and disc >= 0 else 0.0


def match_sharpness(src, ref, src_skin, ref_skin, *, max_gain: float = 2.0, coverage=None,
                    where=None) -> tuple[np.ndarray, float]:
    """(``src`` sharpened, gain g): ``src`` + (g − 1) x its pixel-scale high-pass (``src`` minus
    the mean of its 4 neighbours, −∇²/4), g chosen so that the variance of the 3 x 3 Laplacian of
    the luminance on ``src``'s bool ``src_skin`` pixels equals ``ref``'s on ``ref_skin`` (the
    sharpness the puppet bench measures; a quadratic in g − 1, its larger root), clipped to
    [1, ``max_gain``]: never blurred, never sharpened more than ``max_gain``. The finest band is
    what a video frame's skin has and a resampled average texture lacks; an unsharp mask of
    sigma 1 px raised the mottling between pores instead (0.64 of a GRID driver's Laplacian
    variance at its 2.5 cap). ``coverage`` (H, W) of ``src``: the neighbours' mean is normalized
    by their coverage, so the silhouette's edge against the empty outside does not ring. ``where``
    (H, W) in [0, 1]: the high-pass is added only there, in that proportion (the gain is matched
    with it; default everywhere). Images (H, W, 3) float [0, 1]; the result is clipped to [0, 1]."""
    s = np.asarray(src, np.float32)
    r = np.asarray(ref, np.float32)
    ms, mr = np.asarray(src_skin, bool), np.asarray(ref_skin, bool)
    if ms.sum() < 16 or mr.sum() < 16:
        return s.copy(), 1.0
    if coverage is None:
        hs = _high_pass(s)
    else:
        c = np.asarray(coverage, np.float32)
        num = cv2.filter2D(s * c[..., None], -1, _K4, borderType=cv2.BORDER_REFLECT)
        den = cv2.filter2D(c, -1, _K4, borderType=cv2.BORDER_REFLECT)[..., None]
        hs = s - num / np.maximum(den, 1e-3)
        hs *= (den > 0.99)  # next to the silhouette (partly uncovered neighbours) left alone
    if where is not None:
        hs *= np.asarray(where, np.float32)[..., None]
    # Var(∇²(s + k hs)) = Var(∇² ref) on the skin
    k = _gain_to_variance(_lap(s)[ms], _lap(hs)[ms], float(np.var(_lap(r)[mr])))
    g = float(np.clip(1.0 + k, 1.0, max_gain))
    if g <= 1.0:
        return s.copy(), 1.0
    return np.clip(s + (g - 1.0) * hs, 0.0, 1.0), g


def match_grain(src, ref, skin, *, max_amount: float = 1.0, feather: float = 1.0) -> tuple[np.ndarray, float]:
    """(``src`` with ``ref``'s grain added on ``skin``, amount a): the frame's pixel-scale band
    (−∇²/4 of ``ref``, each channel clipped at :data:`GRAIN_CLIP` robust standard deviations of
    its skin's), times a soft ``skin`` mask (Gaussian, ``feather`` px), times the a in
    [0, ``max_amount``] that brings the variance of the luminance Laplacian on ``skin`` up to
    ``ref``'s (0 when ``src`` already has it). Compositors call this grain matching: below the
    persona photos' resolution (a 360 px GRID frame's face is larger than an LFW photo's) the
    puppet's own detail, even sharpened to its bound, stays smoother than the video it sits in
    (Laplacian variance 0.36-0.72 of the driver's), and a smooth face in a grainy frame looks
    pasted on. The grain is the frame's own, so it moves and flickers with the video; features
    are the caller's to cut out of ``skin``. Images (H, W, 3) float [0, 1]."""
    s = np.asarray(src, np.float32)
    r = np.asarray(ref, np.float32)
    m = np.asarray(skin, bool)
    if m.sum() < 64 or max_amount <= 0:
        return s.copy(), 0.0
    hd = _high_pass(r)
    sd = 1.4826 * np.median(np.abs(hd[m]), axis=0)
    hd = np.clip(hd, -GRAIN_CLIP * sd, GRAIN_CLIP * sd)
    hd *= cv2.GaussianBlur(m.astype(np.float32), (0, 0), feather)[..., None] if feather > 0 else m[..., None]
    a = min(_gain_to_variance(_lap(s)[m], _lap(hd)[m], float(np.var(_lap(r)[m]))), max_amount)
    if a <= 0:
        return s.copy(), 0.0
    return np.clip(s + a * hd, 0.0, 1.0), a
