"""The puppet's fine detail against the driver's frame: its own detail raised
(:func:`match_sharpness`), the frame's grain where its own detail is short (:func:`match_grain`; in
the bands between the pixel and the persona's resolution, :func:`match_grain_bands`),
the driver's lip lines on its lips (:func:`match_lip_detail`) and its lash lines round its eyes
(:func:`match_lid_detail`)."""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from ._contours import EYE, _contour_frame
from ._pixels import _LUMA
from .eyes import EYES

__all__ = ["match_sharpness", "match_grain", "match_grain_bands", "feature_parts", "brow_bands", "grain_fill",
           "GrainFill", "match_lip_detail", "match_lid_detail", "GRAIN_CLIP", "GRAIN_BAND_SIGMAS",
           "GRAIN_TEXTURE_KAPPA", "GRAIN_FILL_STEP", "LIP_DETAIL_SIGMA", "LID_DETAIL_SIGMA", "LID_DETAIL_REACH"]


def _points_box(q: np.ndarray, shape, grow: float) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) int (x, y) of the points ``q`` (k, 2)'s box grown by ``grow`` px, inside an image
    of ``shape`` (H, W, ...)."""
    lo = np.maximum(np.floor(q.min(axis=0) - grow).astype(int), 0)
    hi = np.minimum(np.ceil(q.max(axis=0) + grow).astype(int) + 1, [shape[1], shape[0]])
    return lo, hi


_K4 = np.array([[0, 0.25, 0], [0.25, 0, 0.25], [0, 0.25, 0]], np.float32)
#: the frame's fine band is clipped at this many robust standard deviations of its skin's: the lash
#: lines, glasses rims and creases that survive the feature cut are far stronger than skin grain.
#: At 2.5 the clip took 60 % of a 1000 px studio face's pore-scale variance (its tails are pores and
#: speckle, not lines): the puppet's skin measured 0.60-0.75 of the driver's sharpness on FRL drivers
#: (0.71-0.90 at 4, the dlib identity distances unchanged; GRID's 256 px bench unchanged)
GRAIN_CLIP = 4.0


def _high_pass(x: np.ndarray) -> np.ndarray:
    """The pixel-scale band: ``x`` minus the mean of its 4 neighbours (−∇²/4)."""
    return x - cv2.filter2D(x, -1, _K4, borderType=cv2.BORDER_REFLECT)


def _clip_robust(band: np.ndarray, where: np.ndarray) -> np.ndarray:
    """``band`` clipped at :data:`GRAIN_CLIP` robust standard deviations (1.4826 x the median
    absolute value) of its values on the bool ``where``, per channel when it has channels."""
    sd = 1.4826 * np.median(np.abs(band[where]), axis=0)
    return np.clip(band, -GRAIN_CLIP * sd, GRAIN_CLIP * sd)


#: the rigid offsets of :func:`grain_fill`, in units of its step, nearest first; up first (above
#: the driver's brows lies its forehead)
FILL_OFFSETS = tuple((k * dy, k * dx) for k in (1, 2, 3, 4)
                     for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1)))


#: the step of :func:`grain_fill`'s offsets, as a fraction of the eye-corner distance (about a
#: brow band's height: the first offset up moves it onto the forehead)
GRAIN_FILL_STEP = 0.1


def feature_parts(points68, shape) -> tuple[np.ndarray, np.ndarray]:
    """(brows, eyes and lips): bool (H, W) masks of :func:`~facetex.geometry.masks.feature_mask` at
    iBUG ``points68``; their union is its whole mask."""
    from ..geometry.masks import feature_mask

    return tuple(feature_mask(points68, shape, parts=k) for k in (("brows",), ("eyes", "lips")))


def brow_bands(region, driver_parts, puppet_parts) -> np.ndarray:
    """bool (H, W): the pixels of the bool ``region`` in either face's brow band and in neither's eyes
    or lips (each face's :func:`feature_parts`): where the puppet's skin or brows lie over the
    driver's brows (the frame's grain there is its brow hair)."""
    (brows_d, others_d), (brows_p, others_p) = driver_parts, puppet_parts
    return np.asarray(region, bool) & (brows_d | brows_p) & ~(others_d | others_p)


class GrainFill(NamedTuple):
    """Where :func:`match_grain` and :func:`match_grain_bands` shift the skin's grain in
    (:func:`grain_fill`): the bool ``hole`` (H, W) and the flat indices of its pixels (``dst``) and of
    their source pixels (``src``)."""

    hole: np.ndarray
    dst: np.ndarray
    src: np.ndarray


def grain_fill(skin: np.ndarray, hole: np.ndarray, step: float) -> GrainFill:
    """The :class:`GrainFill` of the bool ``hole``: each of its pixels (not in the bool ``skin``)
    takes the ``skin`` pixel at the first offset of :data:`FILL_OFFSETS` (x ``step`` px) that lands
    on one; pixels no offset reaches are left out. Pass the same ``skin`` to the grain functions."""
    src = np.asarray(skin, bool)
    ys, xs = np.nonzero(np.asarray(hole, bool) & ~src)
    H, W = src.shape
    dst_idx, src_idx = [np.zeros(0, np.intp)], [np.zeros(0, np.intp)]
    for oy, ox in FILL_OFFSETS:
        if ys.size == 0:
            break
        sy, sx = ys + int(round(oy * step)), xs + int(round(ox * step))
        ok = (sy >= 0) & (sy < H) & (sx >= 0) & (sx < W)
        ok[ok] = src[sy[ok], sx[ok]]
        dst_idx.append(ys[ok] * W + xs[ok])
        src_idx.append(sy[ok] * W + sx[ok])
        ys, xs = ys[~ok], xs[~ok]
    return GrainFill(np.asarray(hole, bool), np.concatenate(dst_idx), np.concatenate(src_idx))


def _fill_shifted(band: np.ndarray, fill: GrainFill) -> np.ndarray:
    """``band`` (H, W[, C]) with the hole pixels of ``fill`` copied from their source pixels.
    Neighbouring hole pixels share an offset, so the hole takes rigid, shifted pieces of the skin's
    grain (a shift-map fill, written here: ``cv2.inpaint`` diffuses and leaves a hole smooth, a
    nearest-pixel fill streaks, and :func:`facetex.transfer.detail.fill_from_source`'s blended
    blocks take ~0.1 s a band on a 1000 px frame's face)."""
    out = band.copy()
    flat = out.reshape(band.shape[0] * band.shape[1], -1)
    flat[fill.dst] = band.reshape(flat.shape)[fill.src]
    return out


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


#: the octave bands of :func:`match_grain_bands`: band k is the Gaussian blur of sigma ``[k]`` minus
#: that of sigma ``[k + 1]`` (px); the first edge is the pixel band's (:func:`match_grain`) split
GRAIN_BAND_SIGMAS = (0.7, 1.4, 2.8, 5.6, 11.2)
#: a band's pixels fade as 1 / (1 + (E / (kappa^2 m))^4), E its local energy (Gaussian, twice the
#: band's coarser sigma) and m the median of E on the skin: at kappa times the typical amplitude half,
#: at the typical amplitude 0.996
GRAIN_TEXTURE_KAPPA = 2.0


def _texture_weight(band: np.ndarray, skin: np.ndarray, sigma: float) -> np.ndarray:
    """(H, W) float32 in (0, 1]: 1 / (1 + (E / (kappa^2 m))^4), E the local energy of the luminance
    ``band`` (its square blurred by ``sigma``), m the median of E on the bool ``skin``, kappa
    :data:`GRAIN_TEXTURE_KAPPA`. Stubble, a moustache, a mole or a scar are patches of far stronger
    structure than the pores around them, and stay the driver's (the clip at :data:`GRAIN_CLIP`
    works per pixel)."""
    e = cv2.GaussianBlur(band * band, (0, 0), sigma)
    e /= GRAIN_TEXTURE_KAPPA ** 2 * max(float(np.median(e[skin])), 1e-12)
    return (1.0 / (1.0 + (e * e) ** 2)).astype(np.float32)


def match_grain(src, ref, skin, *, max_amount: float = 1.0, feather: float = 1.0,
                fill: GrainFill | None = None) -> tuple[np.ndarray, float]:
    """(``src`` with ``ref``'s grain added on ``skin``, amount a): the frame's pixel-scale band
    (−∇²/4 of ``ref``, each channel clipped at :data:`GRAIN_CLIP` robust standard deviations of
    its skin's), times a soft ``skin`` mask (Gaussian, ``feather`` px), times the a in
    [0, ``max_amount``] that brings the variance of the luminance Laplacian on ``skin`` up to
    ``ref``'s (0 when ``src`` already has it). Compositors call this grain matching: below the
    persona photos' resolution (a 360 px GRID frame's face is larger than an LFW photo's) the
    puppet's own detail, even sharpened to its bound, stays smoother than the video it sits in
    (Laplacian variance 0.36-0.72 of the driver's), and a smooth face in a grainy frame looks
    pasted on. The grain is the frame's own, so it moves and flickers with the video; features
    are the caller's to cut out of ``skin``. ``fill`` (:func:`grain_fill` of ``skin``): where the
    puppet shows skin and the frame does not (its brows, where the persona's are thinner), the grain
    is the skin's, shifted in; without it such a hole stayed smooth, an arch the shape of the
    driver's brows. Images (H, W, 3) float [0, 1]."""
    s = np.asarray(src, np.float32)
    r = np.asarray(ref, np.float32)
    m = np.asarray(skin, bool)
    if m.sum() < 64 or max_amount <= 0:
        return s.copy(), 0.0
    hd = _high_pass(r)
    hd = _clip_robust(hd, m)
    on = m
    if fill is not None:
        hd, on = _fill_shifted(hd, fill), m | fill.hole
    hd *= cv2.GaussianBlur(on.astype(np.float32), (0, 0), feather)[..., None] if feather > 0 else on[..., None]
    a = min(_gain_to_variance(_lap(s)[m], _lap(hd)[m], float(np.var(_lap(r)[m]))), max_amount)
    if a <= 0:
        return s.copy(), 0.0
    return np.clip(s + a * hd, 0.0, 1.0), a


def match_grain_bands(src, ref, skin, *, reach: float, max_amount: float = 1.0,
                      fill: GrainFill | None = None) -> tuple[np.ndarray, tuple]:
    """(``src`` with ``ref``'s octave bands added on ``skin``, their amounts): for every band of
    :data:`GRAIN_BAND_SIGMAS` whose coarser sigma is at most ``reach`` px, the frame's band (each
    channel clipped at :data:`GRAIN_CLIP` robust standard deviations of its skin's, faded where its
    local energy is far above the skin's (:func:`_texture_weight`), times ``skin`` feathered by the
    band's finer sigma) is added times the a in [0, ``max_amount``] that brings the
    variance of ``src``'s luminance band on ``skin`` up to ``ref``'s (0 where ``src`` has it). A
    persona's texture is a blend of ~100 px LFW faces: drawn on a 1000 px frame its skin has no
    detail between the pixel (the grain of :func:`match_grain`) and a few pixels, and at half the
    size the puppet measured 0.2-0.27 of a studio driver's face sharpness while passing at full size
    (FRL portraits). Without the fade the driver's stubble and spots came with its pores and the
    composites read nearer the driver (dlib, the puppet's distance to its persona minus to the driver
    +0.008 on average, +0.038 on the worst run; +0.004 with it). ``reach``: the caller's bound on
    what the persona lacks (a fraction of the eye distance); the coarser bands carry a face's
    wrinkles and spots, which stay the persona's. ``fill``: as :func:`match_grain`'s.
    Images (H, W, 3) float [0, 1]; the result is not clipped (:func:`match_grain` follows and clips)."""
    s = np.asarray(src, np.float32)
    r = np.asarray(ref, np.float32)
    m = np.asarray(skin, bool)
    edges = [x for x in GRAIN_BAND_SIGMAS if x <= reach]
    if m.sum() < 64 or max_amount <= 0 or len(edges) < 2:
        return s.copy(), ()
    out, amounts = s.copy(), []
    on = m if fill is None else m | fill.hole
    fine_r, fine_s = cv2.GaussianBlur(r, (0, 0), edges[0]), cv2.GaussianBlur(s, (0, 0), edges[0])
    for lo, hi in zip(edges[:-1], edges[1:]):
        coarse_r, coarse_s = cv2.GaussianBlur(r, (0, 0), hi), cv2.GaussianBlur(s, (0, 0), hi)
        br, bs = fine_r - coarse_r, fine_s - coarse_s
        fine_r, fine_s = coarse_r, coarse_s
        if fill is not None:
            br = _fill_shifted(br, fill)
        add = _clip_robust(br, m)
        lr, ls = br @ _LUMA, bs @ _LUMA
        add *= (cv2.GaussianBlur(on.astype(np.float32), (0, 0), lo) * _texture_weight(lr, m, 2 * hi))[..., None]
        la = add @ _LUMA
        a = min(_gain_to_variance(ls[m], la[m], float(np.var(lr[m]))), max_amount)
        if a > 0:
            out += a * add
        amounts.append(max(a, 0.0))
    return out, tuple(amounts)


#: the lips' detail band: the frame's luminance minus its Gaussian blur of this many mouth widths
#: (sigma; at least a pixel): the lines across the lips and their highlights
LIP_DETAIL_SIGMA = 0.02
#: the lip detail fades in from each lip's edges over this share of its thickness: the band there
#: holds the driver's lip outline, which on the puppet's outline drew it as a crisp line
LIP_DETAIL_EDGE = 0.3


def match_lip_detail(src, ref, driver68, puppet68, *, max_amount: float = 1.0) -> tuple[np.ndarray, float]:
    """(``src`` with the driver's lip detail, amount a): the frame ``ref``'s luminance band
    (:data:`LIP_DETAIL_SIGMA`) on each of the driver's lips moved onto the puppet's same lip (every
    puppet lip pixel takes the driver's at the same place between the corners and between the lip's
    outer and inner edge, :func:`~facetex.puppet._contours.sample_between`), clipped at
    :data:`GRAIN_CLIP` robust standard deviations of its value on the driver's lips, faded in from
    the lips' edges (:data:`LIP_DETAIL_EDGE`), added to the three channels times the a in
    [0, ``max_amount``] that brings the variance of the luminance Laplacian on the puppet's lips up
    to the driver's (0 when they have it). The persona's lips are a blend of ~250 px photos: on a
    1000 px driver they were a flat pink patch beside the frame's lined lips; grain from the same
    pixel (:func:`match_grain`) would print the driver's lip edges where the puppet's lips are not.
    ``driver68``, ``puppet68`` (68, 2) px of the images (H, W, 3) float [0, 1]."""
    from ._contours import LIP_BAND, LOWER_LIP, UPPER_LIP, sample_between
    from .mouth import lip_ring

    s = np.asarray(src, np.float32)
    r = np.asarray(ref, np.float32)
    d, p = np.asarray(driver68, np.float64), np.asarray(puppet68, np.float64)
    width = float(np.linalg.norm(d[54] - d[48]))
    if max_amount <= 0 or not np.all(np.isfinite(d[48:68])) or not np.all(np.isfinite(p[48:68])) or width < 8:
        return s.copy(), 0.0
    sigma = max(1.0, LIP_DETAIL_SIGMA * width)

    # only round the lips: the band, rings and Laplacians of a 1000 px frame's face box cost ~25 ms
    dlo, dhi = _points_box(d[48:68], r.shape, 4 * sigma + 2)  # the Gaussian reaches 4 sigma
    plo, phi = _points_box(p[48:68], s.shape, 2)
    if np.any(dhi - dlo < 3) or np.any(phi - plo < 3):
        return s.copy(), 0.0
    rd = np.ascontiguousarray(r[dlo[1]:dhi[1], dlo[0]:dhi[0]])
    sp = s[plo[1]:phi[1], plo[0]:phi[0]]
    dq, pq = d - dlo, p - plo
    ring_d, ring_p = lip_ring(dq, rd.shape), lip_ring(pq, sp.shape)
    if ring_d.sum() < 16 or ring_p.sum() < 16:
        return s.copy(), 0.0
    lum = np.ascontiguousarray(rd @ _LUMA)
    band = lum - cv2.GaussianBlur(lum, (0, 0), sigma)
    band = _clip_robust(band, ring_d)
    add = np.zeros(sp.shape[:2], np.float32)
    for idx in (UPPER_LIP, LOWER_LIP):
        b = sample_between(band, dq[list(idx)], pq[list(idx)], sp.shape[:2], layout=LIP_BAND)
        if b is None:
            continue
        x0, y0, x1, y1 = b.box
        w = b.edge(LIP_DETAIL_EDGE) * (b.depth > 0)
        add[y0:y1, x0:x1] = np.where(w > 0, b.warped * w, add[y0:y1, x0:x1])
    hd = np.repeat(add[..., None], 3, axis=2)
    a = min(_gain_to_variance(_lap(sp)[ring_p], _lap(hd)[ring_p], float(np.var(_lap(rd)[ring_d]))), max_amount)
    out = s.copy()
    if a > 0:
        out[plo[1]:phi[1], plo[0]:phi[0]] = np.clip(sp + a * hd, 0.0, 1.0)
    return out, max(a, 0.0)


#: the lids' detail band: the frame's luminance minus its Gaussian blur of this many eye-corner
#: distances (sigma; at least a pixel): lashes, the lid's margin and its crease
LID_DETAIL_SIGMA = 0.01
#: the lid detail reaches this many eye-corner distances out from each eye's outline (full up to
#: half of it, fading out beyond): the lash lines and the upper lid's crease
LID_DETAIL_REACH = 0.12


def _eye_affine(puppet_eye: np.ndarray, driver_eye: np.ndarray) -> np.ndarray:
    """(2, 3) affine map of puppet px onto driver px for one eye's six points (corner, two upper,
    corner, two lower): corner to corner, and across the eye by the ratio of the two openings
    (clipped to [0.5, 2]; 1 when either eye is nearly shut, where a least-squares fit of six
    points on a line would be unbounded across it)."""
    def frame(q):  # the corners' midpoint, the axes, the width and the opening over the width
        _, R, width, gap = _contour_frame(q, EYE)
        return 0.5 * (q[0] + q[3]), R[0], R[1], max(width, 1e-6), gap / max(width, 1e-6)

    po, pu, pv, pw, pa = frame(np.asarray(puppet_eye, np.float64))
    do, du, dv, dw, da = frame(np.asarray(driver_eye, np.float64))
    k = float(np.clip(da / pa, 0.5, 2.0)) if min(pa, da) > 0.05 else 1.0
    # x -> do + dw/pw * (du (pu.(x - po)) + k dv (pv.(x - po)))
    M = (dw / pw) * (np.outer(du, pu) + k * np.outer(dv, pv))
    return np.c_[M, do - M @ po]


def _lid_ring(points68, shape, reach: float, inside_px: float = 1.5) -> np.ndarray:
    """float32 (H, W): 1 from ``inside_px`` px inside either eye's outline out to half of ``reach``
    px beyond it, falling linearly to 0 at ``reach`` px; 0 deeper inside (the eyeball)."""
    eyes = np.zeros(shape, np.uint8)
    for idx in EYES:  # filled at the rounded points: a tiny eye still has its pixels
        cv2.fillPoly(eyes, [np.round(points68[list(idx)]).astype(np.int32)], 1)
    out = cv2.distanceTransform(1 - eyes, cv2.DIST_L2, 3)
    inn = cv2.distanceTransform(eyes, cv2.DIST_L2, 3)
    ring = np.clip(2.0 * (reach - out) / max(reach, 1e-6), 0.0, 1.0)
    return np.where(eyes > 0, (inn <= inside_px).astype(np.float32), ring).astype(np.float32)


def match_lid_detail(src, ref, driver68, puppet68, *, max_amount: float = 1.0) -> tuple[np.ndarray, float]:
    """(``src`` with the driver's lash lines, amount a): the frame ``ref``'s luminance band
    (:data:`LID_DETAIL_SIGMA`) round each of the driver's eyes (its lids out to
    :data:`LID_DETAIL_REACH`, not its eyeball) moved onto the puppet's same eye (corner to corner,
    scaled across by the ratio of the openings), clipped at :data:`GRAIN_CLIP` robust
    standard deviations of its value there, added round the puppet's eyes (not inside them: the
    eyeballs are drawn apart, :func:`~facetex.puppet.eyes.eye_interior`) to the three channels
    times the a in [0, ``max_amount``] that brings the variance of the luminance Laplacian there up
    to the driver's round its own eyes (0 when they have it). The persona's lids are a blend of
    ~250 px photos: on a 1000 px driver they were a soft grey smear round the driver's sharp
    eyeballs, without lashes or a crease (eye sharpness 0.17-0.42 of the driver's on 36 portrait
    runs). ``driver68``, ``puppet68`` (68, 2) px of the images (H, W, 3) float [0, 1]."""
    s = np.asarray(src, np.float32)
    r = np.asarray(ref, np.float32)
    d, p = np.asarray(driver68, np.float64), np.asarray(puppet68, np.float64)
    if max_amount <= 0 or not (np.all(np.isfinite(d[36:48])) and np.all(np.isfinite(p[36:48]))):
        return s.copy(), 0.0
    iod = float(np.linalg.norm(d[36] - d[45]))
    sigma = max(1.0, LID_DETAIL_SIGMA * iod)
    reach = LID_DETAIL_REACH * iod
    pad = reach + 4 * sigma + 2

    dlo, dhi = _points_box(d[36:48], r.shape, pad)
    plo, phi = _points_box(p[36:48], s.shape, pad)
    if iod < 8 or np.any(dhi - dlo < 8) or np.any(phi - plo < 8):
        return s.copy(), 0.0
    rd = np.ascontiguousarray(r[dlo[1]:dhi[1], dlo[0]:dhi[0]])
    sp = s[plo[1]:phi[1], plo[0]:phi[0]]
    dq, pq = d - dlo, p - plo
    wd, wp = _lid_ring(dq, rd.shape[:2], reach), _lid_ring(pq, sp.shape[:2], reach * float(
        np.linalg.norm(p[36] - p[45])) / iod)
    md, mp = wd > 0.5, wp > 0.5
    if md.sum() < 16 or mp.sum() < 16:
        return s.copy(), 0.0
    lum = np.ascontiguousarray(rd @ _LUMA)
    band = lum - cv2.GaussianBlur(lum, (0, 0), sigma)
    band = _clip_robust(band, md) * wd
    h, w = sp.shape[:2]
    left = (np.arange(w) < 0.5 * (pq[39, 0] + pq[42, 0]))[None, :]  # each eye's half takes its map
    add = np.zeros((h, w), np.float32)
    for idx, side in zip(EYES, (left, ~left)):
        A = _eye_affine(pq[list(idx)], dq[list(idx)])  # puppet px -> driver px
        moved = cv2.warpAffine(band, A, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                               borderMode=cv2.BORDER_CONSTANT)
        add = np.where(side, moved, add)
    hd = np.repeat((add * wp)[..., None], 3, axis=2)
    a = min(_gain_to_variance(_lap(sp)[mp], _lap(hd)[mp], float(np.var(_lap(rd)[md]))), max_amount)
    out = s.copy()
    if a > 0:
        out[plo[1]:phi[1], plo[0]:phi[0]] = np.clip(sp + a * hd, 0.0, 1.0)
    return out, max(a, 0.0)
