"""Eyeglasses in a face photo, from the frame's bridge over the nose.

Hand-written (no package on the registry ships an eyeglasses detector that runs here): the
bridge of a pair of glasses crosses the nose between the inner eye corners as a horizontal
line, where bare skin changes slowly from top to bottom. The score is the strongest row of
vertical gradient across that box over the box's mean horizontal gradient. It separates the
glasses photos of the shared LFW collections from the rest only *relative to the person's
own photos* (skin tone, lighting and the nose's shading set its level), so
:func:`glasses_weights` compares each photo with its collection's median.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["glasses_bridge_score", "glasses_weights"]


def luminance_and_points(image, points68) -> tuple[np.ndarray, np.ndarray | None]:
    """(luminance (H, W) float32 in [0, 1] of ``image`` (uint8 or float [0, 1], RGB(A)), its iBUG-68
    points as float64 (68, 2) or None when they are not 68 finite points): what the per-photo
    eye-region scores (bridge, gaze) start from."""
    img = np.asarray(image)
    lum = img[..., :3].astype(np.float32) @ np.float32([0.299, 0.587, 0.114])
    if img.dtype == np.uint8:
        lum /= 255.0
    p = np.asarray(points68, np.float64)
    return lum, (p if p.shape == (68, 2) and np.isfinite(p).all() else None)


def glasses_bridge_score(image, points68) -> float:
    """Bridge-line score of one face ``image`` (H, W, 3) (uint8 or float [0, 1]) with its iBUG-68
    ``points68`` (68, 2): max over the rows of the box between the inner eye corners (middle 60 %
    of their distance; from 0.3 eye-centre distances above their line to 0.1 below) of the row's
    mean |d/dy| of the luminance (Gaussian sigma 1 px, Sobel), over the box's mean |d/dx| (+1e-3).
    NaN when the box is empty or off the image."""
    lum, p = luminance_and_points(image, points68)
    if p is None:
        return float("nan")
    left, right = p[39], p[42]
    iod = float(np.linalg.norm(p[36:42].mean(0) - p[42:48].mean(0)))
    y_line = (left[1] + right[1]) / 2
    dx = right[0] - left[0]
    x0, x1 = int(round(left[0] + 0.2 * dx)), int(round(right[0] - 0.2 * dx))
    y0, y1 = int(round(y_line - 0.3 * iod)), int(round(y_line + 0.1 * iod))
    h, w = lum.shape
    # a margin of 3 px for the blur and the Sobel
    if x1 - x0 < 2 or y1 - y0 < 2 or x0 < 3 or y0 < 3 or x1 > w - 3 or y1 > h - 3:
        return float("nan")
    crop = cv2.GaussianBlur(lum[y0 - 3:y1 + 3, x0 - 3:x1 + 3], (0, 0), 1.0)
    gy = np.abs(cv2.Sobel(crop, cv2.CV_32F, 0, 1, ksize=3))[3:-3, 3:-3]
    gx = np.abs(cv2.Sobel(crop, cv2.CV_32F, 1, 0, ksize=3))[3:-3, 3:-3]
    return float(gy.mean(axis=1).max() / (gx.mean() + 1e-3))


def glasses_weights(scores, *, level: float = 1.25, power: float = 4.0) -> np.ndarray:
    """(n,) weights in (0, 1] of photos by their :func:`glasses_bridge_score` ``scores`` (n,):
    1 up to ``level`` x the collection's median score, then (score / (level x median)) ** -power
    (the shared LFW collections: glasses photos 1.6-3.6 x their median, photos without 0.3-2.1
    x; a photo without glasses that scores high loses some weight, one with glasses most; at
    level 1.5 Arroyo's puppet still showed faint rims).
    NaN scores (no box) and a collection without a usable median get weight 1."""
    s = np.asarray(scores, np.float64)
    out = np.ones(s.shape)
    ok = np.isfinite(s)
    if ok.sum() < 3 or power <= 0:
        return out
    med = float(np.median(s[ok]))
    if med <= 0:
        return out
    ratio = np.where(ok, s / (level * med), 1.0)
    out = np.clip(ratio, 1.0, None) ** -power
    return out
