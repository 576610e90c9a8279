"""Sideways gaze in a face photo, from the balance of the eyes' whites.

Hand-written (the registry's packaged models here give eyelid landmarks, not the iris): a
face looking at the camera shows white on both sides of the iris; one looking sideways shows
it on one side only. Per eye, the luminance is averaged over the middle rows between the lids
(a column profile across the eye, smoothed), and the mean of its left half above the profile's
darkest value (the iris) is compared with its right half's. The two eyes' signed asymmetries
are averaged: both look the same way, while the nose's shading darkens the inner corners,
which lie on opposite sides for the two eyes and cancel.
"""

from __future__ import annotations

import cv2
import numpy as np

from .glasses import luminance_and_points

__all__ = ["gaze_asymmetry", "gaze_weights"]

#: (eye corners and outline, upper-lid pair, lower-lid pair) of the iBUG-68 eyes
_EYES = ((slice(36, 42), (37, 38), (40, 41)), (slice(42, 48), (43, 44), (46, 47)))


def _eye_profile(lum: np.ndarray, p: np.ndarray, eye) -> np.ndarray | None:
    outline, up, lo = eye
    e = p[outline]
    x0, x1 = float(e[:, 0].min()), float(e[:, 0].max())
    yt, yb = float(p[list(up), 1].mean()), float(p[list(lo), 1].mean())
    h, w = lum.shape
    ya, yb = int(round(yt + 0.2 * (yb - yt))), int(round(yb - 0.2 * (yb - yt))) + 1
    xa, xb = int(np.floor(x0)), int(np.ceil(x1)) + 1
    if x1 - x0 < 4 or ya < 0 or xa < 0 or xb > w or yb > h:
        return None
    prof = lum[ya:max(yb, ya + 1), xa:xb].mean(axis=0).astype(np.float32)
    return cv2.GaussianBlur(prof.reshape(1, -1), (0, 0), max(0.5, 0.08 * (x1 - x0))).ravel()


def gaze_asymmetry(image, points68) -> float:
    """Signed sideways gaze of one face ``image`` (H, W, 3) (uint8 or float [0, 1]) with its
    iBUG-68 ``points68``: per eye, (L − R) / (L + R) with L and R the mean luminance of the left
    and right halves of the eye's middle 70 % (its corners' skin left out) above the darkest value
    there, averaged over both eyes. 0 when the whites show alike on both sides (looking at the
    camera), towards +1 when only the left half (image x) is white (the eyes look to the image's
    right), towards −1 the other way. NaN when the eyes are off the image or too small."""
    lum, p = luminance_and_points(image, points68)
    if p is None:
        return float("nan")
    res = []
    for eye in _EYES:
        prof = _eye_profile(lum, p, eye)
        if prof is None:
            return float("nan")
        n = len(prof)
        a, b, m = int(0.15 * n), int(np.ceil(0.85 * n)), n // 2
        if b - a < 2 or m <= a or m >= b:
            return float("nan")
        low = float(prof[a:b].min())
        left, right = float(prof[a:m].mean()) - low, float(prof[m:b].mean()) - low
        res.append((left - right) / max(left + right, 1e-6))
    return float(np.mean(res))


def gaze_weights(scores, sigma: float = 0.5) -> np.ndarray:
    """(n,) weights in (0, 1] of photos with gaze scores ``scores`` (:func:`gaze_asymmetry`):
    exp(−((s − median) / sigma)²), the median of the finite scores standing for the person's
    straight-ahead look (lighting and the lids' shape bias the score a little); NaN scores get 1.
    ``sigma`` <= 0: all 1."""
    s = np.asarray(scores, np.float64)
    out = np.ones(s.shape)
    ok = np.isfinite(s)
    if sigma <= 0 or not ok.any():
        return out
    out[ok] = np.exp(-(((s[ok] - np.median(s[ok])) / sigma) ** 2))
    return out
