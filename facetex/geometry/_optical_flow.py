"""Optical flow for same-person, illumination-matched images (Tom Hanks §4, §5).

The paper uses Ce Liu's Coarse2FineFlow (Brox et al. 2004 / Bruhn et al. 2005)
with (α, ratio, minWidth, outer, inner, SOR) = (0.02, 0.85, 20, 4, 1, 40), and
α = 0.3 for the collection's dense warping. The default method drives OpenCV's
``VariationalRefinement`` (a Brox-type energy: robust brightness + gradient
constancy + robust smoothness, solved by fixed-point iterations and SOR) over
Liu's pyramid ourselves: levels scaled by ``ratio`` down to ``min_width``
pixels, the flow upsampled between levels and refined with ``outer_iters``
fixed-point and ``sor_iters`` SOR iterations per level.

α mapping: OpenCV normalises its data terms by |∇I|² + ζ² (Zimmer et al. 2011),
so its data cost is ≈ a displacement in pixels whatever the contrast, whereas
Liu's robust, unnormalised cost on [0,1] images grows as |∇I| · displacement.
Matching the two balances gives ``alpha_cv = α / ḡ`` with ḡ the mean gradient
magnitude of the two [0,1] gray images (≈ 0.014-0.024 per pixel on 256² faces,
so α = 0.02 -> alpha_cv ≈ 1-1.4, the optimum region of a sweep over
{0.5, 1, 2, 4} on real faces; α = 0.3 -> ≈ 13-21, a strongly smoothed flow).
δ = γ = 1: brightness and gradient constancy weighted equally, as Liu's
feature image stacks gray and its gradients.
Liu's ``inner_iters`` (lagged-nonlinearity updates per warping step) has no
separate counterpart: each OpenCV fixed-point iteration updates the robust
weights and the linearisation together, so it runs outer_iters × inner_iters.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import BadInputError
from ._flow_core import gray01

_METHODS = ("variational", "dis", "dis_fast", "farneback")


def _to_gray255(img: np.ndarray, name: str) -> np.ndarray:
    return gray01(img, name, 2) * 255


def _pyramid_scales(h: int, w: int, ratio: float, min_width: int) -> list[float]:
    """Scales 1, ratio, ratio², ... while the smaller side stays >= min_width (Liu's Coarse2FineFlow)."""
    scales, s = [1.0], ratio
    while min(h, w) * s >= min_width:
        scales.append(s)
        s *= ratio
    return scales


def _resize_flow(flow: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    sx, sy = size[0] / flow.shape[1], size[1] / flow.shape[0]
    return cv2.resize(flow, size, interpolation=cv2.INTER_LINEAR) * np.array([sx, sy], np.float32)


def _mean_gradient(img255: np.ndarray) -> float:
    gx = cv2.Sobel(img255, cv2.CV_32F, 1, 0, ksize=1)
    gy = cv2.Sobel(img255, cv2.CV_32F, 0, 1, ksize=1)
    return float(np.sqrt(gx * gx + gy * gy).mean()) / (2 * 255)  # central differences, [0,1] units


def _variational_flow(a, b, *, alpha, ratio, min_width, outer_iters, sor_iters):
    h, w = a.shape
    g = 0.5 * (_mean_gradient(a) + _mean_gradient(b))
    vr = cv2.VariationalRefinement.create()
    vr.setAlpha(float(alpha) / max(g, 1e-3))  # Liu's α in OpenCV's normalised units (module docstring)
    vr.setDelta(1.0)
    vr.setGamma(1.0)
    vr.setFixedPointIterations(int(outer_iters))
    vr.setSorIterations(int(sor_iters))
    flow = None
    for s in reversed(_pyramid_scales(h, w, ratio, min_width)):
        size = (max(2, round(w * s)), max(2, round(h * s)))
        if s < 1:  # anti-alias before resampling
            sig = 0.6 * np.sqrt(1 / s - 1)
            a_s = cv2.resize(cv2.GaussianBlur(a, (0, 0), sig), size, interpolation=cv2.INTER_LINEAR)
            b_s = cv2.resize(cv2.GaussianBlur(b, (0, 0), sig), size, interpolation=cv2.INTER_LINEAR)
        else:
            a_s, b_s = a, b
        flow = np.zeros((size[1], size[0], 2), np.float32) if flow is None else _resize_flow(flow, size)
        vr.calc(a_s, b_s, flow)
    return flow


def optical_flow(
    a: np.ndarray,
    b: np.ndarray,
    *,
    alpha: float = 0.02,
    ratio: float = 0.85,
    min_width: int = 20,
    outer_iters: int = 4,
    inner_iters: int = 1,
    sor_iters: int = 40,
    method: str = "variational",
) -> np.ndarray:
    """Dense flow from ``a`` to ``b`` (``a(x) ≈ b(x + F(x))``), float32 (H, W, 2).

    ``a``, ``b``: same-size float RGB/gray images in [0, 1] (uint8 accepted).
    Defaults are Tom Hanks' driver-puppet parameters; use ``alpha=0.3`` for the
    collection's dense warping. ``method``:

    * ``"variational"`` (default) -- Brox/Bruhn coarse-to-fine, OpenCV
      VariationalRefinement driven over Liu's pyramid (all parameters used).
    * ``"dis"`` / ``"dis_fast"`` -- OpenCV DIS (MEDIUM / FAST preset), ~10-100x
      faster, ~3x larger error; the variational parameters are ignored.
    * ``"farneback"`` -- OpenCV Farnebäck polynomial expansion; parameters ignored.
    """
    if method not in _METHODS:
        raise BadInputError(f"unknown optical-flow method {method!r}: use one of {', '.join(_METHODS)}")
    ga, gb = _to_gray255(a, "a"), _to_gray255(b, "b")
    if ga.shape != gb.shape:
        raise BadInputError(f"images differ in size: {ga.shape} vs {gb.shape}; resize one to the other")
    if not 0 < ratio < 1:
        raise BadInputError(f"ratio must be in (0, 1), got {ratio}")
    if min(outer_iters, inner_iters, sor_iters) < 1:
        raise BadInputError("outer_iters, inner_iters and sor_iters must be >= 1")
    if method == "variational":
        return _variational_flow(ga, gb, alpha=alpha, ratio=ratio, min_width=min_width,
                                 outer_iters=outer_iters * inner_iters, sor_iters=sor_iters)
    a8 = np.clip(ga + 0.5, 0, 255).astype(np.uint8)
    b8 = np.clip(gb + 0.5, 0, 255).astype(np.uint8)
    if method in ("dis", "dis_fast"):
        preset = cv2.DISOPTICAL_FLOW_PRESET_MEDIUM if method == "dis" else cv2.DISOPTICAL_FLOW_PRESET_FAST
        return cv2.DISOpticalFlow.create(preset).calc(a8, b8, None)
    return cv2.calcOpticalFlowFarneback(a8, b8, None, 0.5, 5, 15, 5, 7, 1.5, cv2.OPTFLOW_FARNEBACK_GAUSSIAN)
