"""Face masks from 68 landmarks: FaceTex's facial prior (§2.2, §3.1), a soft face region, and
anti-aliased polygon and feature masks (the puppet's composite and the persona's textures use them).

Facial prior (FaceTex §3.1 "Implementation details"): the contours of the meso-structures
(face outline, brows, eyes, nose, lips) are drawn from the landmarks with a 40 px line,
blurred with a Gaussian (kernel 65, sigma 30), normalised to [0, 1] and inverted, so the
meso-structures get the smallest weight; the optimiser's gradient is multiplied by it.
The paper's numbers are for 1000 px headshots; here every length scales with the face
width ``|p16 - p0|`` (jaw ends) relative to :data:`REF_FACE_WIDTH`.

Notes from the authors' code (CNNMRF, ``mylib/maskLoader.lua``, ``mylib/faceprior.lua``):

* the prior is a pre-drawn contour image per content photo (1000 x 1320); the shipped
  ones have ~11 px lines, not 40, and contours spanning 640-700 px across
  (-> :data:`REF_FACE_WIDTH`);
* it calls torch's ``image.gaussian(65, 30)``, whose sigma is *relative to the kernel
  width*, i.e. sigma = 1950 px: effectively a 65 x 65 box filter. We follow the paper's
  text (sigma 30 px); with a 65 px kernel that Gaussian is nearly flat too;
* it min-max normalises, inverts, then **multiplies** by the dataset's person /
  background mask (which includes hair and body). :func:`prior_mask` multiplies by
  :func:`face_mask` instead (face and forehead only, hair and background excluded).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import BadInputError

__all__ = [
    "REF_FACE_WIDTH",
    "disc",
    "MESO_CONTOURS",
    "face_width",
    "forehead_points",
    "face_outline",
    "facial_prior_mask",
    "face_mask",
    "prior_mask",
    "polygon_mask",
    "inner_feather",
    "feature_mask",
    "nose_mask",
    "smoothstep",
]

#: Face width |p16 - p0| (px) of the paper's 1000 px headshots, to which the paper's line
#: width, kernel and sigma refer (the authors' shipped prior contours span 640-700 px).
REF_FACE_WIDTH = 680.0

#: (0-based iBUG indices, closed?) of the contours drawn for the facial prior.
MESO_CONTOURS: tuple[tuple[tuple[int, ...], bool], ...] = (
    (tuple(range(0, 17)), False),  # face outline (jaw)
    (tuple(range(17, 22)), False),  # brows
    (tuple(range(22, 27)), False),
    (tuple(range(27, 31)), False),  # nose bridge
    (tuple(range(31, 36)), False),  # nose base
    (tuple(range(36, 42)), True),  # eyes
    (tuple(range(42, 48)), True),
    (tuple(range(48, 60)), True),  # outer lips
    (tuple(range(60, 68)), True),  # inner lips
)

#: Forehead height above the brows as a fraction of the brow-to-nose-base distance (the
#: "thirds" of the face put the hairline ~1 of that distance above the brows; 0.8 keeps
#: the arc below typical hairlines).
FOREHEAD_RATIO = 0.8
_SHIFT = 4  # sub-pixel bits for OpenCV drawing


def disc(radius: int) -> np.ndarray:
    """OpenCV's elliptical structuring element of ``radius`` px: a disc in a (2 r + 1)² box (r 1: a
    3 x 3 cross)."""
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * int(radius) + 1,) * 2)


def _check(points68, shape):
    p = np.asarray(points68, dtype=np.float64)
    if p.shape != (68, 2) or not np.all(np.isfinite(p)):
        raise BadInputError(f"expected finite (68, 2) landmarks, got shape {p.shape}")
    H, W = int(shape[0]), int(shape[1])
    if H < 1 or W < 1:
        raise BadInputError(f"mask shape must be positive (H, W), got {tuple(shape)[:2]}")
    return p, H, W


def face_width(points68) -> float:
    """|p16 - p0|: distance between the jaw ends (ear level), the face-size unit here."""
    p = np.asarray(points68, dtype=np.float64)
    return max(float(np.linalg.norm(p[16] - p[0])), 1.0)


def _face_frame(p: np.ndarray):
    """Origin (mid jaw ends), x axis (p0 -> p16) and y axis (towards the chin)."""
    o = (p[0] + p[16]) / 2
    ex = (p[16] - p[0]) / face_width(p)
    ey = np.array([-ex[1], ex[0]])
    if (p[8] - o) @ ey < 0:
        ey = -ey
    return o, ex, ey


def forehead_points(points68, n: int = 15, *, ratio: float = FOREHEAD_RATIO) -> np.ndarray:
    """(n, 2) points on an extrapolated forehead arc from near p16 over the top to near p0.

    Half an ellipse in the face's own frame (x along p0 -> p16, y towards the chin): it
    spans the jaw ends and rises ``ratio`` x (brow-to-nose-base distance) above the brows.
    Hand-written heuristic (the 68 points stop at the brows).
    """
    p = np.asarray(points68, dtype=np.float64)
    o, ex, ey = _face_frame(p)
    t = lambda q: (q - o) @ ey  # noqa: E731  (height in the face frame, down positive)
    t_brow = float(np.mean(t(p[17:27])))
    t_top = t_brow - ratio * (float(t(p[33])) - t_brow)
    half = face_width(p) / 2
    ang = np.linspace(0.0, np.pi, n + 2)[1:-1]  # from the p16 side over the top to p0
    s = half * np.cos(ang)
    h = -t_top * np.sin(ang)  # t_top < 0: above the jaw-end line
    return o + s[:, None] * ex + (-h)[:, None] * ey


def face_outline(points68, n_forehead: int = 15) -> np.ndarray:
    """Closed face polygon: jaw 0..16 then the forehead arc back to p0, (17 + n, 2)."""
    p = np.asarray(points68, dtype=np.float64)
    return np.vstack([p[:17], forehead_points(p, n_forehead)])


def _fixed(pts: np.ndarray) -> np.ndarray:
    return np.round(pts * (1 << _SHIFT)).astype(np.int32)


def _odd(v: float) -> int:
    k = max(1, int(round(v)))
    return k if k % 2 else k + 1


def facial_prior_mask(
    points68,
    shape,
    *,
    line_px: float = 40.0,
    ksize: float = 65.0,
    sigma: float = 30.0,
    ref_face_size: float = REF_FACE_WIDTH,
) -> np.ndarray:
    """FaceTex facial prior: float32 (H, W) in [0, 1], smallest on the meso-structures.

    Contours of :data:`MESO_CONTOURS` drawn ``line_px`` wide, blurred with a ``ksize``
    Gaussian of std ``sigma`` (all three in px at face width ``ref_face_size``, scaled
    to this face), min-max normalised and inverted (FaceTex §2.2, §3.1).
    """
    p, H, W = _check(points68, shape)
    scale = face_width(p) / float(ref_face_size)
    canvas = np.zeros((H, W), np.float32)
    thick = max(1, int(round(line_px * scale)))
    for idx, closed in MESO_CONTOURS:
        cv2.polylines(canvas, [_fixed(p[list(idx)])], closed, 1.0, thick, cv2.LINE_AA, _SHIFT)
    k = _odd(ksize * scale)
    blurred = cv2.GaussianBlur(canvas, (k, k), max(sigma * scale, 1e-3), borderType=cv2.BORDER_CONSTANT)
    lo, hi = float(blurred.min()), float(blurred.max())
    if hi - lo <= 1e-12:  # contours entirely outside the image
        return np.ones((H, W), np.float32)
    return (1.0 - (blurred - lo) / (hi - lo)).astype(np.float32)


def face_mask(points68, shape, *, feather: float | None = None) -> np.ndarray:
    """Soft face region (jaw + extrapolated forehead), float32 (H, W) in [0, 1].

    ``feather`` is the Gaussian sigma of the edge in px (default 3 % of the face width);
    the 0.5 level follows :func:`face_outline`. Hair below the arc is not detected.
    """
    p, H, W = _check(points68, shape)
    mask = np.zeros((H, W), np.float32)
    cv2.fillPoly(mask, [_fixed(face_outline(p))], 1.0, cv2.LINE_AA, _SHIFT)
    s = 0.03 * face_width(p) if feather is None else float(feather)
    if s > 0:
        mask = cv2.GaussianBlur(mask, (0, 0), s, borderType=cv2.BORDER_CONSTANT)
    return np.clip(mask, 0.0, 1.0).astype(np.float32)


def prior_mask(points68, shape, **prior_kw) -> np.ndarray:
    """Gradient-scaling mask: facial_prior_mask x face_mask (the authors' code multiplies too)."""
    return (facial_prior_mask(points68, shape, **prior_kw) * face_mask(points68, shape)).astype(np.float32)


_SHIFT = 4  # sub-pixel bits of cv2 polygon filling


def _shape2(shape) -> tuple[int, int]:
    h, w = (int(v) for v in shape[:2])
    return h, w


def polygon_mask(points, shape, *, samples: int = 8) -> np.ndarray:
    """Anti-aliased coverage (H, W) float32 in [0, 1] of the polygon ``points`` (N, 2) x, y
    (pixel centres at integers): the fraction of ``samples`` x ``samples`` sub-pixel sample
    points it covers (cv2.fillPoly on the fine grid, which also counts samples its edges touch:
    the polygon grows by ~0.5 / ``samples`` px; its own LINE_AA grows it by ~0.5 px)."""
    h, w = _shape2(shape)
    p = np.asarray(points, np.float64)
    out = np.zeros((h, w), np.float32)
    if len(p) < 3 or not np.isfinite(p).all():
        return out
    x0, y0 = max(0, int(np.floor(p[:, 0].min()))), max(0, int(np.floor(p[:, 1].min())))
    x1, y1 = min(w, int(np.ceil(p[:, 0].max())) + 1), min(h, int(np.ceil(p[:, 1].max())) + 1)
    if x1 <= x0 or y1 <= y0:
        return out
    k = max(1, int(samples))
    # sample (j, i) of the fine grid sits at ((j + 0.5) / k - 0.5, ...) in box pixels
    q = (p - [x0, y0] + 0.5) * k - 0.5
    fine = np.zeros(((y1 - y0) * k, (x1 - x0) * k), np.uint8)
    cv2.fillPoly(fine, [np.round(q * (1 << _SHIFT)).astype(np.int32)], 255, cv2.LINE_8, _SHIFT)
    out[y0:y1, x0:x1] = cv2.resize(fine, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
    return out


def smoothstep(t):
    """3t² − 2t³ of ``t`` in [0, 1] (clipped by the caller): a ramp with flat ends."""
    return t * t * (3 - 2 * t)


def inner_feather(mask, width: float) -> np.ndarray:
    """Alpha (H, W) float32 rising from 0 at the border of the bool ``mask`` to 1 at ``width``
    px inside it (smoothstep of the distance); 0 outside: the feather never leaves the mask."""
    m = np.asarray(mask, bool)
    if width <= 0:
        return m.astype(np.float32)
    pad = cv2.copyMakeBorder(m.view(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)  # (np.pad is slower)
    d = cv2.distanceTransform(pad, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    t = np.clip((d - 0.5) / float(width), 0.0, 1.0)
    return smoothstep(t).astype(np.float32)


#: the iBUG-68 polygons of :func:`feature_mask`'s eyes and lips
_FEATURE_POLYGONS = {"eyes": (range(36, 42), range(42, 48)), "lips": (range(48, 60),)}


def feature_mask(points68, shape, *, dilate: float = 0.06, parts=("eyes", "brows", "lips")) -> np.ndarray:
    """bool (H, W): eyes, brows and lips (``parts``) of the iBUG-68 ``points68`` (frame px), each
    polygon dilated by ``dilate`` x the outer eye-corner distance: the pixels that are not skin."""
    p = np.asarray(points68, np.float64)
    h, w = _shape2(shape)
    m = np.zeros((h, w), np.float32)
    for idx in (idx for part in ("eyes", "lips") if part in parts for idx in _FEATURE_POLYGONS[part]):
        m = np.maximum(m, polygon_mask(p[list(idx)], (h, w)))
    for idx in (range(17, 22), range(22, 27)) if "brows" in parts else ():
        # brows: a band from the brow to its mirrored lower edge
        b = p[list(idx)]
        m = np.maximum(m, polygon_mask(np.r_[b, b[::-1] + [0, 0.08 * np.ptp(p[:, 1])]], (h, w)))
    iod = float(np.linalg.norm(p[36] - p[45]))
    k = max(1, int(round(dilate * iod)))
    return cv2.dilate((m > 0.5).astype(np.uint8), disc(k)) > 0


def nose_mask(points68, shape, *, grow: float = 0.08) -> np.ndarray:
    """bool (H, W): the lower nose of the iBUG-68 ``points68`` (frame px), from the middle of
    the bridge (point 29) to the tip and the nostrils (31-35), its convex hull grown by ``grow``
    x the outer eye-corner distance (the alae reach past points 31 and 35). The bridge's top is
    left out: a pair of glasses sits there."""
    p = np.asarray(points68, np.float64)
    m = polygon_mask(cv2.convexHull(p[29:36].astype(np.float32))[:, 0], shape) > 0.5
    k = max(1, int(round(grow * float(np.linalg.norm(p[36] - p[45])))))
    return cv2.dilate(m.view(np.uint8), disc(k)) > 0
