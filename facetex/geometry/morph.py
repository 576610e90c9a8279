"""Landmark-driven morphs (FaceTex §2.3; the style-to-content alignment built on them is
:mod:`facetex.geometry.style_align`).

Maps are *absolute sampling maps*: ``map_xy[y, x] = (x', y')`` is where output pixel
(x, y) samples the source image (``cv2.remap`` convention, pixel centres at integers).

* :func:`beier_neely_map` -- Beier & Neely 1992 field morph (FaceTex ref. [1]) driven by
  line segments through the 68 landmarks, an extrapolated forehead arc and the image
  frame (which holds the background in place).
* :func:`piecewise_affine_map` -- Delaunay triangulation of the same points, one affine
  map per triangle (rasterised triangle ids, not scikit-image's per-pixel point location).
* :func:`~facetex.geometry.style_align.align_style_to_content` -- morph the style face onto the content landmarks,
  then refine densely (SIFT flow, FaceTex §2.3) inside the face, composing the maps so the
  style image is resampled once.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import Delaunay

from ..errors import BadInputError
from .masks import disc, face_width, forehead_points
from .tps import ThinPlateSpline

__all__ = [
    "BeierNeelyParams",
    "morph_points",
    "morph_segments",
    "similarity_transform",
    "similarity_frame",
    "jacobian_determinant",
    "unfold_map",
    "beier_neely_lines_map",
    "beier_neely_map",
    "beier_neely_warp",
    "piecewise_affine_map",
    "piecewise_affine_warp",
    "remap",
    "compose_maps",
    "sample_map",
    "invert_map_points",
]


@dataclass(frozen=True)
class BeierNeelyParams:
    """Segment weight = (length^p / (a + dist))^b (Beier & Neely 1992, §3.3).

    a: px, or None for ``a_rel`` x face width (|p16 - p0| of the destination). Small a
       makes the field follow the lines exactly (landmarks land within ~0.1 px); large a
       smooths it. b: how fast influence falls with distance (0.5-2 in the paper).
    p: 0 = all lines equal, 1 = longer lines stronger.
    pin: add a thin-plate spline (lambda 0) of the residuals at the segment end points, so
       every landmark lands exactly: closely spaced segments (a closed mouth's inner lips,
       1-3 px apart) otherwise pull each other by up to ~1 px in the map and ~3 px after
       inversion where the morph compresses.
    inner_lips: also drive the field with the inner-lip segments. Off by default: on a
       closed mouth they lie 1–3 px from each other with opposite directions, and folded
       the map on 11 of 30 FRL pairs (the pin still puts the inner-lip points in place).
    unfold: where the map still folds (Jacobian determinant ≤ 0.02; 3 of 30 pairs, at a
       brow end or a lip corner), blend it locally towards a smooth field (:func:`unfold_map`).
    """

    a: float | None = None
    a_rel: float = 0.005  # ~1.6 px at the 1000 px FRL scale (face width ~325 px)
    b: float = 2.0
    p: float = 0.5
    pin: bool = True
    inner_lips: bool = False
    unfold: bool = True


#: Number of forehead-arc points added above the brows (see masks.forehead_points).
N_FOREHEAD = 7

# segments (index pairs) through the iBUG 68 points: contours of the meso-structures
_CHAINS = (
    (range(0, 17), False),  # jaw
    (range(17, 22), False),  # brows
    (range(22, 27), False),
    (range(27, 31), False),  # nose bridge
    (range(31, 36), False),  # nose base
    (range(36, 42), True),  # eyes
    (range(42, 48), True),
    (range(48, 60), True),  # outer lips
    (range(60, 68), True),  # inner lips
)


def _chain(idx, closed):
    idx = list(idx)
    pairs = list(zip(idx[:-1], idx[1:]))
    return pairs + [(idx[-1], idx[0])] if closed else pairs


def _frame_points(shape) -> np.ndarray:
    """8 points: image corners and edge midpoints (pixel-centre coordinates), clockwise."""
    H, W = shape[0] - 1.0, shape[1] - 1.0
    return np.array([[0, 0], [W / 2, 0], [W, 0], [W, H / 2], [W, H], [W / 2, H], [0, H], [0, H / 2]], dtype=np.float64)


def morph_points(points68, shape, *, n_forehead: int = N_FOREHEAD, frame=None) -> np.ndarray:
    """(68 + n_forehead + 8, 2): the landmarks, a forehead arc (p16 side to p0 side), the frame.

    ``frame``: the 8 frame points to use instead of the corners and edge midpoints of
    ``shape`` (e.g. another image's frame mapped through a similarity)."""
    p = _check68(points68)
    fr = _frame_points(shape) if frame is None else np.asarray(frame, np.float64).reshape(8, 2)
    return np.vstack([p, forehead_points(p, n_forehead), fr])


def similarity_transform(src_points, dst_points) -> np.ndarray:
    """2 × 3 least-squares similarity (rotation, uniform scale, translation) taking
    ``src_points`` (N, 2) to ``dst_points`` (Umeyama 1991, without reflection)."""
    a = np.asarray(src_points, np.float64)
    b = np.asarray(dst_points, np.float64)
    if a.shape != b.shape or a.ndim != 2 or a.shape[1] != 2 or len(a) < 2:
        raise BadInputError(f"similarity_transform needs two (N >= 2, 2) point sets, got {a.shape} and {b.shape}")
    ma, mb = a.mean(0), b.mean(0)
    A, B = a - ma, b - mb
    U, S, Vt = np.linalg.svd(B.T @ A)
    D = np.diag([1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / max((A * A).sum(), 1e-12))
    return np.hstack([s * R, (mb - s * R @ ma)[:, None]])


def similarity_frame(src_points, dst_points, shape) -> np.ndarray:
    """(8, 2) source-image positions of the destination frame (corners and edge midpoints
    of ``shape``) under the landmark similarity destination → source: pinning the frame
    there keeps the morph a near-similarity away from the face, for any crop of either
    image (pinning it to the source image's own frame squeezes a whole photo into a crop)."""
    T = similarity_transform(dst_points, src_points)
    fr = _frame_points(shape)
    return fr @ T[:, :2].T + T[:, 2]


def jacobian_determinant(map_xy: np.ndarray) -> np.ndarray:
    """(H, W) float32 determinant of the sampling map's Jacobian (central differences,
    one-sided at the border). ≤ 0 where the warp folds over (or collapses) the source."""
    m = np.asarray(map_xy, np.float32)
    if m.ndim != 3 or m.shape[2] != 2 or min(m.shape[:2]) < 2:
        raise BadInputError(f"expected an (H, W, 2) map with H, W >= 2, got shape {m.shape}")
    dy = np.gradient(m, axis=0)
    dx = np.gradient(m, axis=1)
    return (dx[..., 0] * dy[..., 1] - dx[..., 1] * dy[..., 0]).astype(np.float32)


def morph_segments(n_forehead: int = N_FOREHEAD, *, inner_lips: bool = True) -> np.ndarray:
    """(S, 2) index pairs into :func:`morph_points`: landmark contours (the inner lips only
    if ``inner_lips``), nose tip -> base, jaw end -> forehead arc -> other jaw end, and the
    image frame loop."""
    chains = _CHAINS if inner_lips else _CHAINS[:-1]
    segs = [s for idx, closed in chains for s in _chain(idx, closed)]
    segs.append((30, 33))
    arc = [16] + list(range(68, 68 + n_forehead)) + [0]
    segs += list(zip(arc[:-1], arc[1:]))
    segs += _chain(range(68 + n_forehead, 68 + n_forehead + 8), True)
    return np.asarray(segs, dtype=np.intp)


def _check68(points68) -> np.ndarray:
    p = np.asarray(points68, dtype=np.float64)
    if p.shape != (68, 2) or not np.all(np.isfinite(p)):
        raise BadInputError(f"expected finite (68, 2) landmarks, got shape {p.shape}")
    return p


def _check_image(image) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim not in (2, 3) or img.shape[0] < 2 or img.shape[1] < 2:
        raise BadInputError(f"expected an (H, W) or (H, W, C) image, got shape {img.shape}")
    return img


def _shape2(shape) -> tuple[int, int]:
    H, W = int(shape[0]), int(shape[1])
    if H < 2 or W < 2:
        raise BadInputError(f"output shape must be at least 2 x 2, got {tuple(shape)[:2]}")
    return H, W


# ---------------------------------------------------------------------------
# Beier-Neely


def beier_neely_lines_map(
    src_lines,
    dst_lines,
    shape,
    *,
    a: float,
    b: float = 2.0,
    p: float = 0.5,
    step: int = 1,
    exact_lines=None,
) -> np.ndarray:
    """(H, W, 2) float32 sampling map of Beier & Neely's multiple-line field morph.

    ``src_lines``, ``dst_lines``: (S, 2, 2) segments (P, Q) as (x, y). Reverse mapping
    (§3.3): destination segment PQ with source segment P'Q' maps X to
    ``X'_i = P' + u (Q' - P') + v perp(Q' - P') / |Q' - P'|`` with
    ``u = (X - P).(Q - P) / |Q - P|^2``, ``v = (X - P).perp(Q - P) / |Q - P|``; the result
    is ``X + sum w_i (X'_i - X) / sum w_i``, ``w_i = (|Q - P|^p / (a + dist_i))^b``, dist
    being the distance from X to the segment PQ. Each segment's map is a similarity, so all
    segments are evaluated at once as affine functions of (x, y) (hand-written: no library
    implements this morph). ``step > 1`` evaluates a grid every ``step`` px, interpolates
    bilinearly and re-evaluates exactly the pixels within ``3 * step`` of the segments
    flagged in ``exact_lines`` (bool (S,), default all), where the weights' cusps (width
    ~a) defeat interpolation.
    """
    H, W = _shape2(shape)
    src_l = np.asarray(src_lines, dtype=np.float64).reshape(-1, 2, 2)
    dst_l = np.asarray(dst_lines, dtype=np.float64).reshape(-1, 2, 2)
    if src_l.shape != dst_l.shape or len(src_l) == 0:
        raise BadInputError(f"src_lines and dst_lines must both be (S, 2, 2), got {src_l.shape} and {dst_l.shape}")
    if not (a > 0 and b >= 0):
        raise BadInputError(f"Beier-Neely needs a > 0 and b >= 0, got a={a}, b={b}")
    exact = np.ones(len(dst_l), bool) if exact_lines is None else np.asarray(exact_lines, bool).copy()
    P, Q = dst_l[:, 0], dst_l[:, 1]
    keep = np.linalg.norm(Q - P, axis=1) > 1e-6  # coincident points (closed lips) give no direction
    P, Q, Ps, Qs, exact = P[keep], Q[keep], src_l[keep, 0], src_l[keep, 1], exact[keep]
    d, ds = Q - P, Qs - Ps
    L = np.linalg.norm(d, axis=1)
    Ls = np.maximum(np.linalg.norm(ds, axis=1), 1e-9)
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / L[:, None]  # unit perpendicular
    ns = np.stack([-ds[:, 1], ds[:, 0]], axis=1) / Ls[:, None]
    # u, v as affine functions of [x, y, 1]: (3, S) coefficient matrices
    Cu = np.vstack([d.T / L**2, -(P * d).sum(1) / L**2])
    Cv = np.vstack([n.T, -(P * n).sum(1)])
    # displacement X'_i - X = P' + u (Q' - P') + v n' - X, again affine in [x, y, 1]
    Cdx = Cu * ds[:, 0] + Cv * ns[:, 0]
    Cdy = Cu * ds[:, 1] + Cv * ns[:, 1]
    Cdx[0] -= 1.0
    Cdy[1] -= 1.0
    Cdx[2] += Ps[:, 0]
    Cdy[2] += Ps[:, 1]
    C = np.hstack([Cu, Cv, Cdx, Cdy]).astype(np.float32)  # (3, 4S): rows multiply x, y, 1
    ev = _BNField(C, L.astype(np.float32), (L**p).astype(np.float32), np.float32(a), float(b))
    step = max(1, int(step))
    if step == 1 or H * W <= 4 * len(L) * step * step:
        yy, xx = np.mgrid[0:H, 0:W]
        return ev(xx.ravel(), yy.ravel()).reshape(H, W, 2)
    gy = np.arange(0, H - 1 + step, step)
    gx = np.arange(0, W - 1 + step, step)
    gxx, gyy = np.meshgrid(gx, gy)
    G = ev(gxx.ravel(), gyy.ravel()).reshape(len(gy), len(gx), 2).astype(np.float64)
    Wy = _linear_weights(np.arange(H, dtype=np.float64), step, len(gy))
    Wx = _linear_weights(np.arange(W, dtype=np.float64), step, len(gx))
    out = np.empty((H, W, 2), dtype=np.float32)
    for k in range(2):
        out[..., k] = Wy @ G[..., k] @ Wx.T
    near = np.zeros((H, W), np.uint8)
    for q0, q1 in zip(P[exact], Q[exact]):
        cv2.line(near, _ipt(q0), _ipt(q1), 1, 2 * _NEAR_STEPS * step + 1)
    ys, xs = np.nonzero(near)
    if len(ys):
        out[ys, xs] = ev(xs, ys)
    return out


def beier_neely_map(
    src_points,
    dst_points,
    shape,
    *,
    a: float | None = None,
    b: float = 2.0,
    p: float = 0.5,
    src_shape=None,
    src_frame=None,
    params: BeierNeelyParams | None = None,
    step: int | None = None,
    fold_mask=None,
) -> np.ndarray:
    """(H, W, 2) float32 sampling map moving ``src_points`` (68, 2) onto ``dst_points``.

    :func:`beier_neely_lines_map` on the segments of :func:`morph_segments` (landmark
    contours, forehead arc, image frame; ``src_shape``: the source image's (H, W) for its
    frame, default ``shape``), then the optional pin correction (:class:`BeierNeelyParams`).
    ``a`` defaults to ``a_rel`` x face width. ``step`` defaults to face width / 80 (4 on a
    325 px wide face); measured max error vs ``step=1`` on a 1000 px FRL pair: 0.07 px at
    step 4, ~6x faster (frame segments map nearly identically, so they get no exact band).
    """
    H, W = _shape2(shape)
    prm = params or BeierNeelyParams(a=a, b=b, p=p)
    src = morph_points(src_points, (H, W) if src_shape is None else _shape2(src_shape), frame=src_frame)
    dst = morph_points(dst_points, (H, W))
    seg = morph_segments(inner_lips=prm.inner_lips)
    fw = face_width(dst[:68])
    A = float(prm.a) if prm.a is not None else prm.a_rel * fw
    step = max(1, int(round(fw / 80 if step is None else step)))
    exact = np.ones(len(seg), bool)
    exact[len(seg) - 8 :] = False  # the frame loop
    out = beier_neely_lines_map(src[seg], dst[seg], (H, W), a=A, b=prm.b, p=prm.p, step=step, exact_lines=exact)
    if not prm.pin and not prm.unfold:
        return out
    check = np.ones((H, W), bool) if fold_mask is None else np.asarray(fold_mask, bool)

    def folds(m):
        return bool(((jacobian_determinant(m) <= _MIN_DET) & check).any())

    sharp = out + _pin_correction(out, src, dst, (H, W)) if prm.pin else out
    if not prm.unfold or not folds(sharp):
        return sharp
    # The map folds: the pin's residual spline between nearly coincident points, or close
    # segments with different transforms (brow end / jaw top, lip corners). Blend it locally
    # towards the first fold-free of: the field without the pin, a smooth field (8 × a),
    # the landmark similarity.
    def smooth():
        return beier_neely_lines_map(src[seg], dst[seg], (H, W), a=8 * A, b=prm.b, p=prm.p, step=step,
                                     exact_lines=exact)

    def similarity():
        T = similarity_transform(dst[:68], src[:68])
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
        return np.stack([T[0, 0] * xx + T[0, 1] * yy + T[0, 2], T[1, 0] * xx + T[1, 1] * yy + T[1, 2]], -1)

    def fold_free(chain):
        # each map in the chain is blended locally towards the (made fold-free) next one
        m = chain[0]()
        if len(chain) == 1 or not folds(m):
            return m
        ref = fold_free(chain[1:])
        return unfold_map(lambda alpha, d=m - ref: ref + alpha[..., None] * d, (H, W), mask=check)

    chain = ([lambda: sharp, lambda: out] if prm.pin else [lambda: out]) + [smooth, similarity]
    return fold_free(chain).astype(np.float32)


_MIN_DET = 0.02  # smallest Jacobian determinant accepted as unfolded (≈ 50× local compression)


def unfold_map(build, shape, *, mask=None, min_det: float = _MIN_DET, iters: int = 20,
               sigma: float | None = None) -> np.ndarray:
    """The map ``build(alpha)`` with a per-pixel blend ``alpha`` in [0, 1] reduced, smoothly,
    where the map folds: ``build(0)`` must be fold-free (e.g. the map without a correction),
    ``build(1)`` is the map wanted. Each round halves ``alpha`` around pixels (in ``mask``,
    default everywhere) whose Jacobian determinant is ≤ ``min_det`` and re-smooths it
    (Gaussian ``sigma`` px, default 2 × the largest |build(1) − build(0)| near the folds,
    at least 3: a steeper alpha folds the map itself); after ``iters`` rounds ``alpha`` is
    ~1e-6 there. Hand-written."""
    H, W = int(shape[0]), int(shape[1])
    alpha = np.ones((H, W), np.float32)
    check = np.ones((H, W), bool) if mask is None else np.asarray(mask, bool)
    m = build(alpha)
    if sigma is None:
        bad = (jacobian_determinant(m) <= min_det) & check
        if not bad.any():
            return m
        d = np.linalg.norm(m - build(np.zeros_like(alpha)), axis=2)
        near = cv2.dilate(bad.astype(np.uint8), disc(15)) > 0
        sigma = float(np.clip(2.0 * d[near].max(), 3.0, 0.1 * max(H, W)))
    for it in range(iters + 1):
        bad = (jacobian_determinant(m) <= min_det) & check
        if not bad.any():
            return m
        if it == iters:
            break
        else:
            r = int(np.ceil(sigma))
            grow = cv2.dilate(bad.astype(np.uint8), disc(r)) > 0
            alpha = np.where(grow, alpha * 0.5, alpha)
            alpha = np.minimum(alpha, cv2.GaussianBlur(alpha, (0, 0), sigma))
        m = build(alpha)
    return m


def _pin_correction(m: np.ndarray, src: np.ndarray, dst: np.ndarray, shape) -> np.ndarray:
    """Dense TPS (lambda 0) of the residuals src - m(dst) at the morph points (merged within 1 px)."""
    res = src - sample_map(m, dst)
    keep_pts, keep_res = [], []
    for q, r in zip(dst, res):  # merge (near-)coincident points, e.g. a closed mouth: mean residual
        for k, kq in enumerate(keep_pts):
            if np.hypot(*(q - kq)) < 1.0:
                keep_res[k].append(r)
                break
        else:
            keep_pts.append(q)
            keep_res.append([r])
    P = np.array(keep_pts)
    R = np.array([np.mean(r, axis=0) for r in keep_res])
    # residuals are ~1 px: interpolation error scales with them, so a small exact zone suffices
    return ThinPlateSpline.fit(P, R, smoothing=0.0).dense_map(shape, step=8, exact_radius=6).astype(np.float32)


_NEAR_STEPS = 3


def _ipt(p) -> tuple[int, int]:
    return int(round(float(p[0]))), int(round(float(p[1])))


def _linear_weights(x: np.ndarray, step: int, n: int) -> np.ndarray:
    """(len(x), n) 1-D linear interpolation weights from nodes 0, step, 2 step, ..."""
    i = np.minimum((x // step).astype(np.intp), n - 2)
    f = x / step - i
    M = np.zeros((len(x), n))
    r = np.arange(len(x))
    M[r, i] = 1.0 - f
    M[r, i + 1] = f
    return M


class _BNField:
    """Evaluates the Beier-Neely displacement field at arbitrary pixels (float32, chunked)."""

    def __init__(self, C, L, Lp, a, b):
        self.C, self.L, self.Lp, self.a, self.b = C, L, Lp, a, b

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x = np.asarray(x, np.float32).ravel()
        y = np.asarray(y, np.float32).ravel()
        S = len(self.L)
        out = np.empty((len(x), 2), np.float32)
        n = max(1, 2**18 // S)
        for i in range(0, len(x), n):
            xi, yi = x[i : i + n, None], y[i : i + n, None]
            T = xi * self.C[0] + yi * self.C[1] + self.C[2]  # (N, 4S)
            u, v, dx, dy = T[:, :S], T[:, S : 2 * S], T[:, 2 * S : 3 * S], T[:, 3 * S :]
            e = np.maximum(np.maximum(-u, u - 1.0), 0.0)
            e *= self.L  # distance beyond an endpoint, along the line
            e *= e
            e += v * v
            np.sqrt(e, out=e)  # distance to the segment
            e += self.a
            np.divide(self.Lp, e, out=e)
            w = e * e if self.b == 2 else e**self.b  # (length^p / (a + dist))^b
            ws = w.sum(1)
            out[i : i + n, 0] = xi[:, 0] + np.einsum("ns,ns->n", w, dx) / ws
            out[i : i + n, 1] = yi[:, 0] + np.einsum("ns,ns->n", w, dy) / ws
        return out


_INTERP = {"linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC, "lanczos": cv2.INTER_LANCZOS4,
           "nearest": cv2.INTER_NEAREST}


def remap(image: np.ndarray, map_xy: np.ndarray, *, border: str = "replicate", interpolation: str = "linear") -> np.ndarray:
    """Sample ``image`` at ``map_xy`` (border 'replicate' or 'constant' 0). ``interpolation``
    'linear' (default), 'cubic', 'lanczos' (keeps pore-level detail: bilinear resampling
    at sub-pixel offsets halves the energy at 2–3 px periods) or 'nearest'."""
    mode = {"replicate": cv2.BORDER_REPLICATE, "constant": cv2.BORDER_CONSTANT}[border]
    if interpolation not in _INTERP:
        raise BadInputError(f"interpolation must be one of {sorted(_INTERP)}, not {interpolation!r}")
    m = np.asarray(map_xy, dtype=np.float32)
    img = np.asarray(image)
    if img.dtype == np.float64:
        img = img.astype(np.float32)
    out = cv2.remap(img, m[..., 0], m[..., 1], _INTERP[interpolation], borderMode=mode)
    if interpolation in ("cubic", "lanczos") and np.issubdtype(img.dtype, np.floating):
        lo, hi = float(img.min()), float(img.max())  # no overshoot beyond the source's range
        np.clip(out, lo, hi, out=out)
    return out


def beier_neely_warp(image, src_points, dst_points, *, output_shape=None, **kw) -> np.ndarray:
    """``image`` morphed so ``src_points`` move to ``dst_points`` (see :func:`beier_neely_map`)."""
    img = _check_image(image)
    shape = img.shape[:2] if output_shape is None else output_shape
    return remap(img, beier_neely_map(src_points, dst_points, shape, src_shape=img.shape[:2], **kw))


# ---------------------------------------------------------------------------
# piecewise affine


def piecewise_affine_map(src_points, dst_points, shape, *, src_shape=None, src_frame=None) -> np.ndarray:
    """(H, W, 2) float32 sampling map, affine on each Delaunay triangle of the destination
    points (landmarks + forehead arc + frame, so the whole image is covered).

    Triangle ids are rasterised with ``cv2.fillConvexPoly`` and each pixel applies its
    triangle's affine (neighbours agree on shared edges, so edge pixels are exact).
    """
    H, W = _shape2(shape)
    src = morph_points(src_points, (H, W) if src_shape is None else _shape2(src_shape), frame=src_frame)
    dst = morph_points(dst_points, (H, W))
    tri = Delaunay(dst).simplices
    Dt = dst[tri]  # (T, 3, 2)
    e1, e2 = Dt[:, 1] - Dt[:, 0], Dt[:, 2] - Dt[:, 0]
    area = np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    tri, Dt = tri[area > 1e-9], Dt[area > 1e-9]
    # affine M (T, 2, 3) with M @ [dst, 1] = src on the 3 vertices
    Dh = np.concatenate([Dt, np.ones((len(tri), 3, 1))], axis=2)  # (T, 3, 3)
    M = np.linalg.solve(Dh, src[tri]).transpose(0, 2, 1)  # (T, 2, 3)
    ids = np.full((H, W), -1, np.int32)
    for k, t in enumerate(Dt):
        cv2.fillConvexPoly(ids, np.round(t * 16).astype(np.int32), k, cv2.LINE_8, 4)
    if (ids < 0).any():  # outside the hull (only if the frame points were moved): nearest id
        _, lab = cv2.distanceTransformWithLabels((ids < 0).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
        src_idx = np.flatnonzero((ids >= 0).ravel())
        zeros_lab = lab.ravel()[src_idx]
        lut = np.zeros(lab.max() + 1, np.int32)
        lut[zeros_lab] = ids.ravel()[src_idx]
        ids = np.where(ids < 0, lut[lab], ids)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    Mi = M.astype(np.float32)[ids]  # (H, W, 2, 3)
    out = np.empty((H, W, 2), np.float32)
    out[..., 0] = Mi[..., 0, 0] * xx + Mi[..., 0, 1] * yy + Mi[..., 0, 2]
    out[..., 1] = Mi[..., 1, 0] * xx + Mi[..., 1, 1] * yy + Mi[..., 1, 2]
    return out


def piecewise_affine_warp(image, src_points, dst_points, *, output_shape=None) -> np.ndarray:
    """``image`` warped piecewise-affinely so ``src_points`` move to ``dst_points``."""
    img = _check_image(image)
    shape = img.shape[:2] if output_shape is None else output_shape
    return remap(img, piecewise_affine_map(src_points, dst_points, shape, src_shape=img.shape[:2]))


# ---------------------------------------------------------------------------
# map utilities


def compose_maps(outer: np.ndarray, inner: np.ndarray) -> np.ndarray:
    """Map of sampling ``outer``'s image through ``inner`` first: result(x) = outer(inner(x))."""
    return remap(outer, inner)


def sample_map(map_xy: np.ndarray, points) -> np.ndarray:
    """Bilinear values of ``map_xy`` at (N, 2) float positions (border replicated), float64."""
    m = np.asarray(map_xy, dtype=np.float64)
    H, W = m.shape[:2]
    p = np.asarray(points, dtype=np.float64)
    x = np.clip(p[:, 0], 0, W - 1)
    y = np.clip(p[:, 1], 0, H - 1)
    x0 = np.minimum(np.floor(x).astype(np.intp), W - 2)
    y0 = np.minimum(np.floor(y).astype(np.intp), H - 2)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    return (
        m[y0, x0] * (1 - fx) * (1 - fy)
        + m[y0, x0 + 1] * fx * (1 - fy)
        + m[y0 + 1, x0] * (1 - fx) * fy
        + m[y0 + 1, x0 + 1] * fx * fy
    )


def invert_map_points(map_xy: np.ndarray, points, init=None, *, iters: int = 20) -> np.ndarray:
    """Output positions x with map_xy(x) = points: where source points land after the warp.

    Newton iterations with the map's finite-difference Jacobian, from ``init`` (default:
    the points themselves).
    """
    p = np.asarray(points, dtype=np.float64)
    x = p.copy() if init is None else np.asarray(init, dtype=np.float64).copy()
    e = np.array([[0.5, 0.0], [0.0, 0.5]])
    for _ in range(iters):
        r = p - sample_map(map_xy, x)
        if np.abs(r).max() < 1e-4:
            break
        J = np.stack(
            [(sample_map(map_xy, x + e[k]) - sample_map(map_xy, x - e[k])) for k in range(2)], axis=2
        )  # (N, 2, 2): d map / d x_k in column k
        det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
        ok = np.abs(det) > 1e-6
        step = r.copy()  # fallback: identity Jacobian
        step[ok] = np.linalg.solve(J[ok], r[ok][..., None])[..., 0]
        x += np.clip(step, -20, 20)
    return x


