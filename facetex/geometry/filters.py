"""Image filters shared by the transfer's finishing steps and the metrics (pure numpy / OpenCV)."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import BadInputError

__all__ = ["gaussian", "masked_lowpass"]


def gaussian(a: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur (σ px, reflected border); ``sigma`` ≤ 0 returns ``a``."""
    a = np.asarray(a, np.float32)
    return a if sigma <= 0 else cv2.GaussianBlur(a, (0, 0), float(sigma), borderType=cv2.BORDER_REFLECT)


def masked_lowpass(image, mask, sigma: float, *, eps: float = 1e-4) -> np.ndarray:
    """Normalised convolution ``G_σ * (m x) / G_σ * m`` (Knutsson & Westin 1993): the Gaussian
    low-pass of ``image`` ((H, W) or (H, W, C)) from the pixels of ``mask`` only (weights in
    [0, 1]), so what lies outside the mask never bleeds in; 0 where the mask's blurred weight
    is below ``eps`` (no mask near)."""
    x = np.asarray(image, np.float32)
    m = np.clip(np.asarray(mask, np.float32), 0.0, 1.0)
    if m.shape != x.shape[:2]:
        raise BadInputError(f"mask has shape {m.shape}, the image {x.shape[:2]}")
    if not sigma > 0:
        raise BadInputError(f"sigma must be > 0, got {sigma}")
    w = gaussian(m, sigma)
    mm = m[..., None] if x.ndim == 3 else m
    mx = gaussian(x * mm, sigma)
    ok = w > eps
    den = np.where(ok, w, 1.0)
    if x.ndim == 3:
        den, ok = den[..., None], ok[..., None]
    return np.where(ok, mx / den, 0.0).astype(np.float32)
