"""A feature's opening between two landmark curves (the inner lips, the lids), and the driver's
pixels moved into the puppet's: shared by :mod:`facetex.puppet.mouth` and
:mod:`facetex.puppet.eyes`. Written by hand: no library maps one two-curve opening onto another."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry.masks import smoothstep

#: (right corner, upper curve, lower curve, point pairs across the opening) of the iBUG inner-lip
#: contour 60-67 and of an eye contour 36-41 or 42-47, indices into the contour's points
LIPS = (4, (0, 1, 2, 3, 4), (0, 7, 6, 5, 4), ((1, 7), (2, 6), (3, 5)))
EYE = (3, (0, 1, 2, 3), (0, 5, 4, 3), ((1, 5), (2, 4)))
#: a lip as its own two-curve band between the outer corners 48 and 54: the upper lip's points
#: 48-54 then 64-60 (:data:`UPPER_LIP`), the lower's 48, 60, 67-64, 54-59 (:data:`LOWER_LIP`)
LIP_BAND = (6, (0, 1, 2, 3, 4, 5, 6), (0, 11, 10, 9, 8, 7, 6), ((2, 10), (3, 9), (4, 8)))
UPPER_LIP = (48, 49, 50, 51, 52, 53, 54, 64, 63, 62, 61, 60)
LOWER_LIP = (48, 60, 67, 66, 65, 64, 54, 55, 56, 57, 58, 59)
#: the soft edges of the driver's mouth interior and eyeballs drawn into the puppet's: a ramp of
#: 0.3 x the opening (a pixel or three on a 256 px GRID face) but at most this many pixels, never
#: under :data:`EDGE_MIN_SOFT` x the opening: on a 1000 px driver's smile (a 50 px gap) the ramp
#: and its lip shade were a 15 px dark maroon band between the teeth and the lower lip (FRL 002,
#: every persona), round the eyes a 10 px blur between the whites and the lids
EDGE_MAX_PX = 4.0
EDGE_MIN_SOFT = 0.12


def _contour_frame(points: np.ndarray, layout=LIPS) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(centre, rotation (2, 2) whose rows are the u (corner to corner) and v axes, width, opening:
    the mean distance of the point pairs across it) of a closed contour with ``layout``."""
    corner, _, _, pairs = layout
    c = points.mean(axis=0)
    u = points[corner] - points[0]
    width = float(np.linalg.norm(u))
    u = u / max(width, 1e-9)
    R = np.array([u, [-u[1], u[0]]])
    gap = float(np.mean([np.linalg.norm(points[a] - points[b]) for a, b in pairs]))
    return c, R, width, gap


def _mouth_frame(lips: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """:func:`_contour_frame` of an inner-lip contour 60-67 (8, 2)."""
    return _contour_frame(lips, LIPS)


def _open_fade(width: float, gap: float, closed: float) -> float:
    """0 for a gap up to ``closed`` x the ``width``, 1 from twice that, smooth between."""
    return float(smoothstep(float(np.clip((gap / max(width, 1e-6) - closed) / closed, 0.0, 1.0))))


def _pchip(x: np.ndarray, y: np.ndarray):
    """Monotone piecewise-cubic Hermite interpolant of the points (x, y) (x increasing, >= 2
    points; Fritsch-Carlson slopes with the end rule of scipy's PchipInterpolator, the end cubics
    continued beyond the ends). Written out because scipy's PchipInterpolator spends ~1 ms
    checking its input, four times a frame; tested against it."""
    h = np.diff(x)
    d = np.diff(y) / h
    m = np.zeros_like(y)
    if len(x) == 2:
        m[:] = d[0]
    else:
        w1, w2 = 2 * h[1:] + h[:-1], h[1:] + 2 * h[:-1]
        same = (np.sign(d[1:]) == np.sign(d[:-1])) & (d[1:] != 0) & (d[:-1] != 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            hm = (w1 + w2) / (w1 / d[:-1] + w2 / d[1:])
        m[1:-1] = np.where(same, hm, 0.0)
        for end, (h0, h1, d0, d1) in ((0, (h[0], h[1], d[0], d[1])), (-1, (h[-1], h[-2], d[-1], d[-2]))):
            e = ((2 * h0 + h1) * d0 - h0 * d1) / (h0 + h1)
            if np.sign(e) != np.sign(d0):
                e = 0.0
            elif np.sign(d0) != np.sign(d1) and abs(e) > abs(3 * d0):
                e = 3 * d0
            m[end] = e

    def f(t):
        t = np.asarray(t, np.float64)
        k = np.clip(np.searchsorted(x, t) - 1, 0, len(x) - 2)
        s = (t - x[k]) / h[k]
        s2, s3 = s * s, s * s * s
        return ((2 * s3 - 3 * s2 + 1) * y[k] + (s3 - 2 * s2 + s) * h[k] * m[k] + (-2 * s3 + 3 * s2) * y[k + 1]
                + (s3 - s2) * h[k] * m[k + 1])

    return f


def _contour_arcs(points: np.ndarray, R: np.ndarray, c: np.ndarray, layout=LIPS):
    """(upper, lower, u0, u1): the contour in its own frame (u along the corner line, v across it,
    v growing towards the lower curve) as two smooth curves v(u) through its upper and lower
    points (monotone cubic, PCHIP: no overshoot between the landmarks) over the corners' u range
    [u0, u1]; None when the contour is degenerate."""
    corner, upper, lower, _ = layout
    q = (points - c) @ R.T
    u0, u1 = float(q[0, 0]), float(q[corner, 0])
    if not u1 - u0 > 1e-3:
        return None
    arcs = []
    for idx in (upper, lower):
        u, v = q[list(idx), 0], q[list(idx), 1]
        u = np.clip(u, u0, u1)  # points beyond a corner (noisy landmarks) are held at it
        order = np.argsort(u, kind="stable")
        u, v = u[order], v[order]
        keep = np.r_[True, np.diff(u) > 1e-3 * (u1 - u0)]
        u, v = u[keep], v[keep]
        if len(u) < 2:
            return None
        arcs.append(_pchip(u, v))
    return arcs[0], arcs[1], u0, u1


@dataclass(frozen=True)
class Between:
    """The puppet's opening and the driver's pixels at the same places in it (see :func:`sample_between`).

    ``box`` (x0, y0, x1, y1) of the puppet's opening in output px; per box pixel: ``gap`` (px) of
    the opening at its place along the corner line, ``depth`` (px) inside the contour (negative
    outside), ``warped`` (h, w, 3) the driver's pixel there. ``driver`` (upper, lower, u0, u1, R, c,
    width) the driver's curves and frame."""

    box: tuple[int, int, int, int]
    gap: np.ndarray
    depth: np.ndarray
    warped: np.ndarray
    driver: tuple
    across: np.ndarray | None = None

    def ramp_width(self, soft: float, *, max_px: float | None = None, min_soft: float = EDGE_MIN_SOFT) -> float:
        """The width in px of :meth:`edge`'s ramp: ``soft`` x the widest gap inside the contour (at
        least a pixel; with ``max_px``, a ramp wider than that many pixels is ``max_px``, never less
        than ``min_soft`` x the gap)."""
        g = float(self.gap.max())
        width = soft * g
        if max_px is not None and width > max_px:
            width = max(max_px, min(min_soft, soft) * g)
        return max(width, 1.0)

    def edge(self, soft: float, *, max_px: float | None = None, min_soft: float = EDGE_MIN_SOFT) -> np.ndarray:
        """Alpha (h, w) of the box: 0 outside the contour, rising to 1 over :meth:`ramp_width`. A
        pixel's centre half a pixel inside is half covered (as an anti-aliased polygon's edge); an
        opening thinner than a pixel is covered by its thickness (a closed contour: nothing)."""
        width = self.ramp_width(soft, max_px=max_px, min_soft=min_soft)
        return (smoothstep(np.clip((self.depth + 0.5) / width, 0.0, 1.0)) * np.clip(self.gap, 0.0, 1.0)
                ).astype(np.float32)


def sample_between(frame: np.ndarray, driver: np.ndarray, puppet: np.ndarray, shape: tuple[int, int], *,
                   layout=LIPS, inset: float = 1.0, edge_margin: tuple[float, float] | None = None) -> Between | None:
    """The driver's ``frame`` pixels moved into the puppet's opening: every puppet pixel takes the
    driver's pixel at the same place between the corners (along the corner line) and between the
    upper and lower curve (across it), both scaled about the centre by ``inset`` (along the corner
    line at most 1: beyond the driver's corners lies its skin, not its lips). ``edge_margin`` (m, r)
    px, instead of a scale across the opening: a puppet pixel at depth d < r from the upper or lower
    curve samples the driver's m x (1 - d / r) px further out (beyond its curve at the curve itself),
    deeper ones at their own place: the edge looks as an inset's does, the middle keeps its size.
    ``driver``, ``puppet``: the contours (frame px, output px of ``shape`` (h, w)). None when a
    contour is degenerate or the box is empty."""
    h, w = shape
    cd, Rd, wd, _ = _contour_frame(driver, layout)
    cp, Rp, _, _ = _contour_frame(puppet, layout)
    arcs_p, arcs_d = _contour_arcs(puppet, Rp, cp, layout), _contour_arcs(driver, Rd, cd, layout)
    if arcs_p is None or arcs_d is None:
        return None
    x0, y0 = (max(0, int(np.floor(v)) - 1) for v in puppet.min(axis=0))
    x1, y1 = min(w, int(np.ceil(puppet[:, 0].max())) + 2), min(h, int(np.ceil(puppet[:, 1].max())) + 2)
    if x1 <= x0 or y1 <= y0:
        return None
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float64)
    q = np.stack([xx - cp[0], yy - cp[1]], axis=-1) @ Rp.T
    u, v = q[..., 0], q[..., 1]
    up_p, lo_p, pu0, pu1 = arcs_p
    up_d, lo_d, du0, du1 = arcs_d
    uc = np.clip(u, pu0, pu1)
    a, b = up_p(uc), lo_p(uc)
    gap = np.maximum(b - a, 0.0)
    # depth inside (px): to the nearer curve across the opening, to the nearer corner along it
    depth = np.minimum(np.minimum(v - a, b - v), np.minimum(u - pu0, pu1 - u))
    su = 0.5 + min(inset, 1.0) * ((uc - pu0) / (pu1 - pu0) - 0.5)
    across = np.clip((v - a) / np.maximum(gap, 1e-6), 0.0, 1.0)
    if edge_margin is None:
        sv = 0.5 + inset * (across - 0.5)
    else:
        m, r = edge_margin

        def push(depth):  # the outward shift at a depth from a curve, in gaps
            return m * np.clip(1.0 - depth / max(r, 1e-6), 0.0, 1.0) / np.maximum(gap, 1e-6)

        sv = across - push(np.maximum(v - a, 0.0)) + push(np.maximum(b - v, 0.0))
    ud = du0 + su * (du1 - du0)
    vd = up_d(ud) + sv * (lo_d(ud) - up_d(ud))
    xy = np.stack([ud, vd], axis=-1) @ Rd + cd
    warped = cv2.remap(np.asarray(frame, np.float32), xy[..., 0].astype(np.float32), xy[..., 1].astype(np.float32),
                       cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return Between((x0, y0, x1, y1), gap, depth, warped, (up_d, lo_d, du0, du1, Rd, cd, wd), across)
