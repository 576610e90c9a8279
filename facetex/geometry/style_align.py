"""FaceTex's style-to-content alignment (FaceTex §2.3): the style face morphed onto the content's
landmarks (:mod:`facetex.geometry.morph`), then refined densely by SIFT flow inside the face, the maps
composed so the style is resampled once."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..errors import BadInputError
from .masks import face_mask, face_width
from .morph import BeierNeelyParams, _check68, _check_image, beier_neely_map, compose_maps, invert_map_points, jacobian_determinant, piecewise_affine_map, remap, similarity_frame, unfold_map

__all__ = [
    "AlignParams",
    "AlignResult",
    "refinement_weight",
    "align_style_to_content",
]


# --------------------------------------------------------------------------- FaceTex alignment


@dataclass(frozen=True)
class AlignParams:
    """Dense refinement after the morph (FaceTex §2.3 "Pre-processing").

    The flow is kept to the face (face_mask of the content landmarks), faded out near the
    landmarks (1 - exp(-d^2 / 2 r^2), r = ``landmark_radius`` x face width; the morph
    already puts them in place) and clipped to ``max_shift`` x face width. The flow is
    estimated on the face's bounding box grown by ``crop_margin`` x face width.
    Measured on 4 FRL pairs at 1000 px, re-detected landmark error (px) / gradient NCC in
    the face, SIFT flow [optical flow]: no refinement 2.83 / 0.515; radius 0, cap 0.05:
    3.20 / 0.662 [3.72 / 0.651]; 0.03, 0.05: 3.08 / 0.571 [3.11 / 0.570]; 0.08, 0.05:
    2.91 / 0.523 [2.54 / 0.533]; 0.03, 0.02: 2.60 / 0.569 [2.72 / 0.566]; 0.03, 1.0:
    3.11 / 0.565 [3.62 / 0.570]. Unconstrained flow aligns contours best but drags the
    features; the defaults (0.03, 0.02) improve both measures. The flow is then smoothed
    (``flow_smooth``): only its contour-scale trend is kept, which is what the refinement
    is for ("to further align the face contour"), and the style's pores are carried by a
    locally near-similar map.
    """

    landmark_radius: float = 0.03
    max_shift: float = 0.02
    crop_margin: float = 0.1
    flow_smooth: float = 0.05  # Gaussian sigma of the flow × face width: the flow between two
    # people follows their pores too, and at 0.015 it swirled the style's texture (FRL 083←005 chin)
    beier_neely: BeierNeelyParams = field(default_factory=BeierNeelyParams)


@dataclass
class AlignResult:
    """image: style warped onto the content geometry (content's (H, W)); map_xy: the
    (H, W, 2) absolute sampling map into the style image (warp other data with
    :func:`remap`); points: the style landmarks after the warp (68, 2); timings: seconds."""

    image: np.ndarray
    map_xy: np.ndarray
    points: np.ndarray
    timings: dict = field(default_factory=dict)
    #: face pixels (content face mask > 0.5) where the map folds (Jacobian determinant ≤ 0)
    folds: int = 0


_METHODS = ("beier-neely", "piecewise-affine")
_REFINE = ("sift-flow", "optical-flow", None)
_FRAMES = ("similarity", "image")


def refinement_weight(content_points, shape, params: AlignParams = AlignParams()) -> np.ndarray:
    """(H, W) float32 in [0, 1]: face mask x fade-out near the landmarks (see AlignParams)."""
    p = _check68(content_points)
    H, W = int(shape[0]), int(shape[1])
    marks = np.ones((H, W), np.uint8)
    for x, y in np.round(p).astype(int):
        if 0 <= x < W and 0 <= y < H:
            marks[y, x] = 0
    d = cv2.distanceTransform(marks, cv2.DIST_L2, 5)
    r = params.landmark_radius * face_width(p)
    fade = 1.0 - np.exp(-(d * d) / (2 * r * r)) if r > 0 else np.ones_like(d)
    return (face_mask(p, (H, W)) * fade).astype(np.float32)


def align_style_to_content(
    style: np.ndarray,
    content: np.ndarray,
    *,
    style_points=None,
    content_points=None,
    method: str = "beier-neely",
    refine: str | None = "sift-flow",
    params: AlignParams | None = None,
    flow_kw: dict | None = None,
    frame: str = "similarity",
    interpolation: str = "linear",
) -> AlignResult:
    """Warp ``style`` onto the face geometry of ``content`` (FaceTex §2.3 "Pre-processing").

    ``content`` may be any crop of a photo (its landmarks in crop coordinates): the
    morph's frame points are pinned where a landmark similarity puts them in the style
    image (``frame="similarity"``, :func:`similarity_frame`), so the style keeps its scale
    and the area around the face maps as a near-similarity. ``frame="image"`` pins the
    content's frame onto the style image's frame (only right for two uncropped photos
    framed alike). ``interpolation`` of the final resampling ('lanczos' keeps pores).

    1. landmarks (detected with :func:`facetex.landmarks.detect_face` when not given);
    2. morph the style landmarks onto the content's (Beier-Neely, ref. [1], or piecewise
       affine);
    3. ``refine``: dense flow from the content to the morphed style (``sift_flow`` for
       different people, ref. [14]; or ``optical_flow``), restricted by
       :func:`refinement_weight`, composed with the morph map, so the style is resampled
       once. ``flow_kw`` goes to the flow function.
    """
    if method not in _METHODS:
        raise BadInputError(f"unknown alignment method {method!r}: use one of {', '.join(_METHODS)}")
    if refine not in _REFINE:
        raise BadInputError(f"unknown refinement {refine!r}: use 'sift-flow', 'optical-flow' or None")
    if frame not in _FRAMES:
        raise BadInputError(f"unknown frame mode {frame!r}: use 'similarity' or 'image'")
    prm = params or AlignParams()
    style = _check_image(style)
    content = _check_image(content)
    t = {}
    t0 = time.perf_counter()
    if style_points is None or content_points is None:
        from ..landmarks import detect_face

        if style_points is None:
            style_points = detect_face(style).points68
        if content_points is None:
            content_points = detect_face(content).points68
    sp, cp = _check68(style_points), _check68(content_points)
    t["landmarks"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    shape = content.shape[:2]
    src_frame = similarity_frame(sp, cp, shape) if frame == "similarity" else None
    face = face_mask(cp, shape) > 0.5
    near_face = cv2.dilate(face.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    if method == "beier-neely":
        bn = prm.beier_neely
        m = beier_neely_map(sp, cp, shape, src_shape=style.shape[:2], src_frame=src_frame, params=bn,
                            fold_mask=near_face)
    else:
        m = piecewise_affine_map(sp, cp, shape, src_shape=style.shape[:2], src_frame=src_frame)
    t["morph"] = time.perf_counter() - t0

    t["refine"] = 0.0
    if refine is not None:
        t0 = time.perf_counter()
        from . import flow as _flow

        morphed = remap(style, m)
        wgt = refinement_weight(cp, shape, prm)
        # match only on the face's bounding box (+ margin): cheaper, keeps hair/background out
        ys, xs = np.nonzero(wgt > 1e-3)
        f = np.zeros((*shape, 2), np.float32)
        if len(ys):
            pad = int(round(prm.crop_margin * face_width(cp)))
            y0, y1 = _span(ys.min() - pad, ys.max() + 1 + pad, shape[0])
            x0, x1 = _span(xs.min() - pad, xs.max() + 1 + pad, shape[1])
            est = _flow.sift_flow if refine == "sift-flow" else _flow.optical_flow
            crop = (slice(y0, y1), slice(x0, x1))
            f[crop] = est(_as_float_rgb(content[crop]), _as_float_rgb(morphed[crop]), **(flow_kw or {}))
        f *= wgt[..., None]
        cap = prm.max_shift * face_width(cp)
        mag = np.linalg.norm(f, axis=2, keepdims=True)
        f *= np.minimum(1.0, cap / np.maximum(mag, 1e-9))
        if prm.flow_smooth > 0:  # flow between two people is noisy at pixel scale; only its trend helps
            f = cv2.GaussianBlur(f, (0, 0), prm.flow_smooth * face_width(cp)) * wgt[..., None]
        base = m
        m = unfold_map(lambda alpha: compose_maps(base, _flow.map_from_flow((f * alpha[..., None]).astype(np.float32))),
                       shape, mask=near_face)
        t["refine"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    image = remap(style, m, interpolation=interpolation)
    points = invert_map_points(m, sp, init=cp)
    folds = int(np.count_nonzero((jacobian_determinant(m) <= 0) & face))
    t["warp"] = time.perf_counter() - t0
    t["total"] = sum(t.values())
    return AlignResult(image=image, map_xy=m, points=points, timings=t, folds=folds)


def _span(lo: int, hi: int, n: int, mult: int = 64) -> tuple[int, int]:
    """[lo, hi) clipped to [0, n), length rounded to a multiple of ``mult`` where possible
    (pyramids then halve exactly; OpenCV's INTER_AREA rejects > 4 channels otherwise)."""
    lo, hi = max(0, int(lo)), min(n, int(hi))
    length = -(-(hi - lo) // mult) * mult
    if length > n:
        length = n // mult * mult if n >= mult else n
    lo = min(max(0, (lo + hi - length) // 2), n - length)
    return lo, lo + length


def _as_float_rgb(img: np.ndarray) -> np.ndarray:
    a = np.asarray(img)
    if a.dtype == np.uint8:
        return a.astype(np.float32) / 255.0
    return a.astype(np.float32, copy=False)
