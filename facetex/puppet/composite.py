"""Putting a rendered puppet face into the driver's frame (Tom Hanks §6, beyond the paper).

The paper shows its puppets alone (Figs. 8-9). A puppet composited over the driver's video
looks pasted on unless its colour, lighting and outline come from the frame it sits in:

* **mask**: the driver's own face outline (MediaPipe's face-oval vertices of the frame's
  tracked mesh), intersected with the rendered puppet and feathered *inwards* only, so no
  puppet pixel lands on the driver's background or hair (no halo);
* **lighting** (optional, ``lighting="sh"``): first-order spherical harmonics
  (Y = [1, n_x, n_y, n_z]; Basri & Jacobs 2003, Ramamoorthi & Hanrahan 2001) fitted to the
  linear-light luminance of the driver's skin (with the driver's own tracked mesh normals) and
  of the rendered puppet (with the normals of the puppet's average shape); the puppet is
  multiplied by the ratio of the two shadings. Not the default: on GRID's frontally lit clips
  the ratio mostly turned the albedo baked into the persona's average texture (stubble, lips,
  the collection's top light) into a beard-like darkening around the mouth;
* **skin colour** (default): the low-frequency CIELAB colour of the puppet's skin replaced by
  the driver's, both measured on skin pixels only (each face's own skin colour model: eyes,
  brows, lips, nostrils, hair, stubble and shadows left out), with robust (median-trimmed)
  statistics and a bounded lightness-detail gain, the persona's detail kept
  (:func:`transfer_skin_colour`). One mean shift over the whole face (Reinhard et al. 2001, still
  :func:`match_color_statistics`) kept a dark persona's own shading at its full depth on a pale
  driver: purple-brown patches round the eyes and on the cheeks, and left a pale persona's
  blotches on a flushed driver (cheek ΔE to the driver's own cheeks: median 11, worst 19 over
  6 personas x 6 GRID clips; now 3.5 and 6.2; see :class:`CompositeParams`). ``colour="persona"`` keeps the persona's skin tone and takes only the
  driver's lighting;
* **occlusion**: what lies over the driver's face (a fringe, glasses, a hand of another colour:
  not its skin by its own colour model, outside its eyes, brows and lips) stays in front of the
  puppet (:func:`occlusion_mask`);
* **sharpness**: the puppet's pixel-scale detail is raised to the driver's frame's (bounded
  gain, :func:`match_sharpness`): the persona's texture has been resampled four times
  (frontalized, aligned, blended, rendered) and its small collections' photos are soft, so a
  puppet sat in a video frame as a smooth mask (skin detail 0.34-0.68 of the driver's, Laplacian
  variance, on the 44-71-photo personas);
* **gradient-domain blending**: the puppet's gradients with the driver's values on the mask
  border (Pérez et al. 2003; ``seamlessClone``'s guidance field solved in float32 by the DST), so
  the colour is continuous across the border;
* **mouth interior**: the driver's own mouth interior (teeth, tongue, dark cavity), each
  puppet pixel taking the driver's pixel at the same place between the mouth corners and
  between the upper and lower inner lip (smooth curves through the landmarks), drawn inside the
  puppet's inner lips with a soft edge while the driver's lips are apart, the driver's lip
  colour keyed out.

Plus the measure of the result: :func:`boundary_color_step` (ΔE between bands just inside and
just outside the mask edge).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import BadInputError
from ..geometry.masks import feature_mask, inner_feather, polygon_mask, smoothstep

__all__ = [
    "FACE_OVAL",
    "srgb_to_linear",
    "linear_to_srgb",
    "sh_basis",
    "fit_sh_lighting",
    "sh_shading",
    "relight",
    "match_color_statistics",
    "skin_low_pass",
    "transfer_skin_colour",
    "lip_weights",
    "eye_weights",
    "skin_pixels",
    "occlusion_mask",
    "match_sharpness",
    "poisson_blend",
    "mouth_interior",
    "mouth_closure",
    "fill_mouth_interior",
    "boundary_color_step",
    "CompositeParams",
    "composite_face",
]

#: MediaPipe 468-mesh vertices on the face outline (forehead top, temples, jaw, chin), in order.
FACE_OVAL = (10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377, 152,
             148, 176, 149, 150, 136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109)
#: iBUG-68 inner-lip contour, in order (left corner, upper lip, right corner, lower lip).
INNER_LIPS = (60, 61, 62, 63, 64, 65, 66, 67)

_LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)  # linear-light luminance (Rec. 709)


def _shape2(shape) -> tuple[int, int]:
    h, w = (int(v) for v in shape[:2])
    return h, w


# numpy broadcasts over a length-3 inner axis (an (H, W) weight or a (3,) colour against an
# (H, W, 3) image) and gathers (H, W, 3) pixels by a bool mask several times slower than the same
# arithmetic one channel at a time / np.take on flat indices: the helpers below do that
def _mix(alpha, a, b) -> np.ndarray:
    """alpha * a + (1 - alpha) * b of (H, W) ``alpha`` and (H, W, 3) float32 images."""
    out = np.empty(np.shape(a), np.float32)
    beta = 1 - alpha
    for c in range(3):
        out[..., c] = alpha * a[..., c] + beta * b[..., c]
    return out


def _pixels(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """img[mask] (N, 3) of an (H, W, 3) image and an (H, W) bool mask."""
    return np.ascontiguousarray(img).reshape(-1, 3).take(np.flatnonzero(mask), axis=0)


def _shift(img: np.ndarray, by) -> np.ndarray:
    """img + by of an (H, W, 3) float32 image and a (3,) colour."""
    out = np.empty(img.shape, np.float32)
    for c in range(3):
        np.add(img[..., c], by[c], out=out[..., c])
    return out


# ----------------------------------------------------------------------------- lighting
def srgb_to_linear(x):
    """sRGB-encoded [0, 1] -> linear light (IEC 61966-2-1)."""
    x = np.asarray(x, np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((np.maximum(x, 0.04045) + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(x):
    """Linear light -> sRGB-encoded [0, 1] (clipped)."""
    x = np.clip(np.asarray(x, np.float32), 0, 1)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.maximum(x, 0.0031308) ** (1 / 2.4) - 0.055).astype(np.float32)


def sh_basis(normals) -> np.ndarray:
    """First-order spherical-harmonics basis [1, n_x, n_y, n_z] (..., 4) of unit normals (..., 3)
    (the constant factors of Y_00 and Y_1m are folded into the lighting coefficients)."""
    n = np.asarray(normals, np.float32)
    return np.concatenate([np.ones(n.shape[:-1] + (1,), np.float32), n], axis=-1)


def fit_sh_lighting(image, normals, mask, *, iters: int = 4, ridge: float = 1e-3) -> np.ndarray:
    """(4, C) first-order SH lighting of ``image`` (H, W, C) (linear light, constant albedo
    folded in) from unit ``normals`` (H, W, 3) over the bool ``mask``: per channel
    I ≈ Y(n) · l, fitted by iteratively reweighted least squares (Cauchy weights, scale
    2.2 x the median absolute residual) so that eyebrows, stubble, highlights and cast shadows
    count little. ``ridge`` damps the three directional terms (a frontal face's n_z is almost
    constant)."""
    img = np.asarray(image, np.float32)
    m = np.asarray(mask, bool)
    if img.ndim != 3 or normals.shape[:2] != img.shape[:2] or m.shape != img.shape[:2]:
        raise BadInputError(f"image {img.shape}, normals {np.shape(normals)} and mask {m.shape} must share (H, W)")
    C = img.shape[2]
    if m.sum() < 8:
        out = np.zeros((4, C), np.float32)
        out[0] = img[m].mean(axis=0) if m.any() else 0.5
        return out
    Y = sh_basis(normals[m]).astype(np.float64)
    v = img[m].astype(np.float64)
    w = np.ones(len(Y))
    reg = np.diag([0.0, ridge, ridge, ridge]) * len(Y)
    coef = np.zeros((4, C))
    for _ in range(max(1, iters)):
        Yw = Y * w[:, None]
        coef = np.linalg.solve(Yw.T @ Y + reg * w.mean(), Yw.T @ v)
        r = np.abs(v - Y @ coef).mean(axis=1)
        s = 2.2 * max(float(np.median(r)), 1e-4)
        w = 1.0 / (1.0 + (r / s) ** 2)
    return coef.astype(np.float32)


def sh_shading(normals, coeffs) -> np.ndarray:
    """Shading (..., C) = Y(n) · l of normals (..., 3) under SH lighting ``coeffs`` (4, C)."""
    return sh_basis(normals) @ np.asarray(coeffs, np.float32)


def relight(image, normals, src_light, dst_light, *, limits=(0.5, 2.0), floor: float = 0.25) -> np.ndarray:
    """``image`` (linear light) lit by ``src_light`` re-lit by ``dst_light``: multiplied per
    channel by the shading ratio Y(n)·l_dst / Y(n)·l_src (clipped to ``limits``; the source
    shading is floored at ``floor`` x its lighting's constant term, where a normal facing away
    from the light would make the ratio explode)."""
    src = np.asarray(src_light, np.float32)
    s0 = sh_shading(normals, src)
    s1 = sh_shading(normals, dst_light)
    ratio = np.clip(s1 / np.maximum(s0, floor * np.maximum(src[0], 1e-4)), *limits)
    return (np.asarray(image, np.float32) * ratio).astype(np.float32)


# ----------------------------------------------------------------------------- colour statistics
def _lab(rgb):
    """CIELAB (L* 0..100) of sRGB [0, 1]: OpenCV's conversion of the linear-light values. Its own
    float sRGB path interpolates a 3-D table: a* and b* move in steps of up to 0.4 for a 1e-5 change
    of the input (0.6 off the exact values), which the skin colour transfer turned into 1.2/255
    jumps of single pixels between two puppets 0.01/255 apart; this one is continuous (within 0.03
    of the exact conversion) at 1.4x its cost."""
    return cv2.cvtColor(srgb_to_linear(np.clip(np.asarray(rgb, np.float32), 0, 1)), cv2.COLOR_LRGB2Lab)


def _rgb(lab):
    return np.clip(cv2.cvtColor(np.asarray(lab, np.float32), cv2.COLOR_Lab2RGB), 0, 1)


def match_color_statistics(src, ref, src_mask, ref_mask=None, *, std: bool = False,
                           max_gain: float = 2.0) -> np.ndarray:
    """``src`` (H, W, 3) sRGB with its CIELAB mean over ``src_mask`` moved to ``ref``'s mean over
    ``ref_mask`` (default the same mask) and, with ``std``, its per-channel spread scaled to
    ``ref``'s (gain clipped to [1/max_gain, max_gain]) (Reinhard et al. 2001, in CIELAB rather
    than lαβ). Applied to the whole image; returns sRGB float32 (clipped to [0, 1])."""
    sm = np.asarray(src_mask, bool)
    rm = sm if ref_mask is None else np.asarray(ref_mask, bool)
    if not sm.any() or not rm.any():
        return np.asarray(src, np.float32).copy()
    # only the masked pixels of ``ref`` and of the round trips are converted (OpenCV converts
    # pixel by pixel: the same values as converting the whole image)
    a = _lab(src)
    pa, pb = _pixels(a, sm), _lab(_pixels(ref, rm)[None])[0]
    mu_a, mu_b = pa.mean(axis=0), pb.mean(axis=0)
    if std:
        g = np.clip(pb.std(axis=0) / np.maximum(pa.std(axis=0), 1e-6), 1 / max_gain, max_gain)
    else:
        g = np.ones(3, np.float32)
    lab = np.empty(a.shape, np.float32)
    for c in range(3):
        lab[..., c] = (a[..., c] - mu_a[c]) * g[c] + mu_b[c]
    out = _rgb(lab)
    for _ in range(2):  # OpenCV's float Lab <-> RGB round trip is good to ~0.1 L: re-centre on it
        lab = _shift(lab, mu_b - _lab(_pixels(out, sm)[None])[0].mean(axis=0))
        out = _rgb(lab)
    return out


def skin_low_pass(lab, skin, sigma: float, *, trim: float = 3.0, floor: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Low-frequency colour (H, W, 3) of the ``skin`` pixels (bool (H, W)) of ``lab`` (H, W, 3)
    and their median (3,): a normalized convolution (Gaussian ``sigma`` px) of the skin pixels,
    each channel clipped to its median ± ``trim`` x 1.4826 MAD first (stray hair, shadows and
    highlights the mask let through count as the median's bound); where the skin is further than
    ~2 sigma away (eyes, mouth, outside the face) it tends to the median (``floor``: the weight
    of the median against the skin's blurred coverage). ``sigma`` inf: the median everywhere."""
    x = np.asarray(lab, np.float32)
    m = np.asarray(skin, bool)
    px = _pixels(x, m)
    med = np.median(px, axis=0).astype(np.float32)
    if not np.isfinite(sigma):
        return np.broadcast_to(med, x.shape), med
    mad = np.maximum(1.4826 * np.median(np.abs(px - med), axis=0), 1.0)
    mf = m.astype(np.float32)
    num = np.empty(x.shape, np.float32)
    for c in range(3):
        num[..., c] = np.clip(x[..., c], med[c] - trim * mad[c], med[c] + trim * mad[c]) * mf
    num = cv2.GaussianBlur(num, (0, 0), sigma)
    den = cv2.GaussianBlur(mf, (0, 0), sigma) + floor
    out = np.empty(x.shape, np.float32)
    for c in range(3):
        out[..., c] = (num[..., c] + floor * med[c]) / den
    return out, med


COLOURS = ("driver", "persona")


def _lightness_to_luminance(L):
    """CIE 1976 L* (0..100) -> relative luminance Y (0..1), floored at 1e-4."""
    f = (np.asarray(L, np.float32) + 16) / 116
    return np.maximum(np.where(f > 6 / 29, f ** 3, 3 * (6 / 29) ** 2 * (f - 4 / 29)), 1e-4).astype(np.float32)


def transfer_skin_colour(src, ref, src_skin, ref_skin, *, sigma: float, gain=(2 / 3, 1.2), colour: str = "driver",
                         light_limits=(0.5, 2.0), shrink: int = 1, lips=None, lids=None, keep=None) -> np.ndarray:
    """``src`` (H, W, 3) sRGB with the low-frequency colour of ``ref`` (the same size, aligned),
    measured on skin pixels only (bool ``src_skin``, ``ref_skin``), the detail of ``src`` kept.

    In CIELAB, with low-passes S, R of the two skins and their medians s, r
    (:func:`skin_low_pass`, Gaussian ``sigma`` px): ``colour="driver"``:
    out = R + (g, 1, 1) (src − S), the lightness detail gain g = r_L / s_L clipped to ``gain``
    (a dark persona's iris and lids keep their contrast on a pale driver, a pale persona's pores
    do not turn coarse on a dark one); the persona's own shading and blotches below ~``sigma``
    become the driver's, so they cannot be amplified into bruises. ``colour="persona"``: only the
    lighting moves: linear-light R, G, B x (Y(R_L) / Y(r_L)) / (Y(S_L) / Y(s_L)), the driver's
    low-frequency luminance ratio over the persona's (Y(L*) the CIE luminance, the ratio clipped
    to ``light_limits``), the persona's chromaticity kept.
    ``shrink`` > 1: the low-frequency fields are computed on both images shrunk by that factor
    (area average; ``src_skin`` and ``ref_skin`` are given at the shrunk size) and resized back
    (bilinear): the same fields at a fraction of the cost.
    ``lips`` (colour "driver"): (weight (H, W) in [0, 1], bool (H, W) lip pixels of both images)
    or None: where the weight is 1 the low-frequency colour is the lips' own, out = r' + (g, 1, 1)
    (src − s'), r' and s' the two lip medians: lips are not skin, and the skin's field gave a
    dark persona's lips, lighter than her skin, a pale driver's skin tone plus that difference
    (white lips; a pale driver's lips are darker than her skin). ``keep`` (colour "driver"):
    weight (H, W) in [0, 1] or None: where it is 1 ``src`` is kept as it is (the eyeballs,
    :func:`eye_weights`: iris and whites are not skin; with the skin's field and the bounded
    lightness gain a dark persona's brown irises turned grey on a pale driver). ``lids`` (colour
    "driver"): the same as ``lips`` for the skin round the eyes (:func:`lid_weights`): a dark
    persona's lids, darker than her skin, kept that difference on a pale driver as dark rings.
    Returns sRGB float32 in [0, 1]."""
    if colour not in COLOURS:
        raise BadInputError(f"unknown colour {colour!r}: use one of {', '.join(COLOURS)}")
    sm, rm = np.asarray(src_skin, bool), np.asarray(ref_skin, bool)
    if sm.sum() < 8 or rm.sum() < 8:
        return np.asarray(src, np.float32).copy()
    src = np.asarray(src, np.float32)
    h, w = _shape2(src.shape)
    k = max(1, int(shrink))
    small = (sm.shape[1], sm.shape[0])
    if k > 1:
        s_small, r_small = (cv2.resize(np.asarray(x, np.float32), small, interpolation=cv2.INTER_AREA) for x in (src, ref))
    else:
        s_small, r_small = src, ref
    sa, ca = skin_low_pass(_lab(s_small), sm, sigma / k)
    sb, cb = skin_low_pass(_lab(r_small), rm, sigma / k)

    def full(x):
        return cv2.resize(x, (w, h), interpolation=cv2.INTER_LINEAR) if k > 1 else x

    if colour == "persona":
        # the ratio in linear light, applied to R, G and B alike: the persona's chromaticity kept
        lum = _lightness_to_luminance
        r = full(np.clip((lum(sb[..., 0]) / lum(cb[0])) / (lum(sa[..., 0]) / lum(ca[0])), *light_limits))
        lin = srgb_to_linear(src)
        for c in range(3):
            lin[..., c] *= r
        return linear_to_srgb(lin)
    # lightness detail scales with the skin's lightness (L* ~ Y^(1/3), albedo x shading): a dark
    # persona's iris, lids and pores keep their contrast on a pale driver; chroma detail is kept.
    # out = R + (g, 1, 1) (src - S) = (g, 1, 1) src + field
    g = np.float32([np.clip(cb[0] / max(float(ca[0]), 1.0), *gain), 1.0, 1.0])
    field = np.empty(sa.shape, np.float32)
    for c in range(3):
        field[..., c] = sb[..., c] - g[c] * sa[..., c]
    field = full(field)
    a = _lab(src)
    ref_lab = None
    for region in (lips, lids):
        if region is None:
            continue
        wl, lm = np.asarray(region[0], np.float32), np.asarray(region[1], bool)
        if lm.sum() >= 8 and wl.max() > 0:
            ref_lab = _lab(ref) if ref_lab is None else ref_lab
            own = np.median(_pixels(ref_lab, lm), axis=0) - g * np.median(_pixels(a, lm), axis=0)
            for c in range(3):
                field[..., c] += wl * (own[c] - field[..., c])
    out = np.empty(a.shape, np.float32)
    for c in range(3):
        out[..., c] = g[c] * a[..., c] + field[..., c]
    if keep is not None:
        k = np.asarray(keep, np.float32)[..., None]
        out += k * (a - out)
    return _rgb(out)


def lip_weights(points68, shape, *, feather: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """(weight (H, W) float32, bool (H, W)) of the lips at iBUG landmarks ``points68``: the outer
    lip polygon 48-59 feathered by ``feather`` x the eye-corner distance (Gaussian sigma), and the
    lip pixels themselves (outer polygon minus inner 60-67, a pixel in from both edges) where
    their colour is measured (:func:`transfer_skin_colour`)."""
    p = np.asarray(points68, np.float64)
    h, w = _shape2(shape)
    outer = polygon_mask(p[48:60], (h, w))
    inner = polygon_mask(p[60:68], (h, w))
    ring = ((outer > 0.5) & ~(inner > 0.5)).astype(np.uint8)
    ring = cv2.erode(ring, np.ones((3, 3), np.uint8)) > 0
    sig = max(0.75, feather * float(np.linalg.norm(p[36] - p[45])))
    return np.clip(cv2.GaussianBlur(outer.astype(np.float32), (0, 0), sig), 0, 1), ring


def _scaled(weights: tuple, strength: float) -> tuple:
    """(weight x ``strength``, pixels): a region weight of :func:`transfer_skin_colour` in part."""
    return np.asarray(weights[0], np.float32) * float(np.clip(strength, 0.0, 1.0)), weights[1]


def lid_weights(points68, shape, *, margin: float = 0.045, feather: float = 0.015) -> tuple[np.ndarray, np.ndarray]:
    """(weight (H, W) float32, bool (H, W)) of the lids round both eyes at iBUG landmarks
    ``points68``: the eye outlines (36-41, 42-47) grown by ``margin`` x the face width (the
    margin :func:`facetex.geometry.skin.feature_mask` leaves out of the skin) minus the eyeballs,
    feathered by ``feather`` x the eye-corner distance, and the ring's pixels (a pixel in from
    both edges) where its colour is measured (:func:`transfer_skin_colour`)."""
    from ..geometry.masks import face_width

    p = np.asarray(points68, np.float64)
    h, w = _shape2(shape)
    balls = np.maximum(polygon_mask(p[36:42], (h, w)), polygon_mask(p[42:48], (h, w))) > 0.5
    r = max(1, int(round(margin * face_width(p))))
    grown = cv2.dilate(balls.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)) > 0
    ring = grown & ~balls
    inner = cv2.erode(ring.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    sig = max(0.75, feather * float(np.linalg.norm(p[36] - p[45])))
    return np.clip(cv2.GaussianBlur(grown.astype(np.float32), (0, 0), sig), 0, 1), inner


def eye_weights(points68, shape, *, feather: float = 0.015) -> np.ndarray:
    """Weight (H, W) float32 in [0, 1] of the eyeballs at iBUG landmarks ``points68``: both eye
    outlines (36-41, 42-47, the lids' edges) feathered by ``feather`` x the eye-corner distance
    (Gaussian sigma) inwards: the lids' skin outside them is not counted."""
    p = np.asarray(points68, np.float64)
    h, w = _shape2(shape)
    m = np.maximum(polygon_mask(p[36:42], (h, w)), polygon_mask(p[42:48], (h, w)))
    sig = max(0.5, feather * float(np.linalg.norm(p[36] - p[45])))
    inner = cv2.erode((m > 0.5).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(np.float32)
    return np.clip(cv2.GaussianBlur(inner, (0, 0), sig), 0, 1) * (m > 0.5)


# ----------------------------------------------------------------------------- skin and occluders
def skin_pixels(image, points68, region) -> tuple[np.ndarray | None, np.ndarray]:
    """(bool (H, W) or None, bool (H, W)): the pixels of the bool ``region`` of ``image``
    (H, W, 3) sRGB outside the grown eyes, brows, lips and nostrils that have the face's own skin
    colour (chromaticity and lightness, :func:`facetex.geometry.skin.skin_colour_distance`, fitted
    robustly to that region: hair, stubble, shadows and glasses frames fall out), and those
    features (:func:`facetex.geometry.skin.feature_mask`). None when fewer than 20 pixels are left
    to fit the colour."""
    from ..geometry.skin import SkinParams, feature_mask as grown_features, skin_colour_distance

    sp = SkinParams()
    feats = grown_features(points68, region.shape, sp)
    base = region & ~feats
    if base.sum() < 20:
        return None, feats
    chroma, z = skin_colour_distance(image, points68, region=base)
    return base & (chroma < sp.chroma_sigmas) & (z > -sp.dark_sigmas), feats


def occlusion_mask(region, skin, features, points68, *, min_size: float = 0.03, apart: float = 0.06,
                   margin: float = 0.02, soft: float = 0.01) -> np.ndarray:
    """float32 (H, W) in [0, 1]: what lies over the driver's face (a fringe, glasses, a hand of
    another colour): pixels of the bool ``region`` (the face outline) that are neither ``skin``
    nor ``features`` (the bool pair of :func:`skin_pixels` on the driver's frame: its eyes, brows,
    lips and nostrils are replaced by the puppet's). A piece counts when more than (``min_size``
    x face width)² of it lies further than ``apart`` x face width from the features (a mole or a
    crease's shadow is smaller; the brow hairs and nostril shadows beyond the landmark polygons
    lie next to them); it is grown by ``margin`` x face width (strand tips, frame edges) and
    softened by a Gaussian of ``soft`` x face width."""
    from ..geometry.masks import face_width

    out = np.zeros(np.shape(region), np.float32)
    if skin is None:
        return out
    fw = face_width(points68)
    bad = (region & ~features & ~skin).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(bad, connectivity=8)
    if n < 2:
        return out
    r = max(1, int(round(apart * fw)))
    near = cv2.dilate(features.view(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)) > 0
    away = np.bincount(lab[~near], minlength=n)  # each piece's pixels away from the features
    big = np.flatnonzero(away[1:] >= (min_size * fw) ** 2) + 1
    if not len(big):
        return out
    occ = np.isin(lab, big).astype(np.uint8)
    r = int(round(margin * fw))
    if r >= 1:
        occ = cv2.dilate(occ, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2))
    occ = occ.astype(np.float32)
    if soft * fw > 0.3:  # 1 up to the grown edge, falling to 0 over ~2 sigma outside it
        occ = np.minimum(2 * cv2.GaussianBlur(occ, (0, 0), soft * fw), 1.0)
    return occ * region


def match_sharpness(src, ref, src_skin, ref_skin, *, max_gain: float = 2.0, coverage=None) -> tuple[np.ndarray, float]:
    """(``src`` sharpened, gain g): ``src`` + (g − 1) x its pixel-scale high-pass (``src`` minus
    the mean of its 4 neighbours, −∇²/4), g chosen so that the variance of the 3 x 3 Laplacian of
    the luminance on ``src``'s bool ``src_skin`` pixels equals ``ref``'s on ``ref_skin`` (the
    sharpness the puppet bench measures; a quadratic in g − 1, its larger root), clipped to
    [1, ``max_gain``]: never blurred, never sharpened more than ``max_gain``. The finest band is
    what a video frame's skin has and a resampled average texture lacks; an unsharp mask of
    sigma 1 px raised the mottling between pores instead (0.64 of a GRID driver's Laplacian
    variance at its 2.5 cap). ``coverage`` (H, W) of ``src``: the neighbours' mean is normalized
    by their coverage, so the silhouette's edge against the empty outside does not ring. Images
    (H, W, 3) float [0, 1]; the result is clipped to [0, 1]."""
    s = np.asarray(src, np.float32)
    r = np.asarray(ref, np.float32)
    ms, mr = np.asarray(src_skin, bool), np.asarray(ref_skin, bool)
    if ms.sum() < 16 or mr.sum() < 16:
        return s.copy(), 1.0
    k4 = np.array([[0, 0.25, 0], [0.25, 0, 0.25], [0, 0.25, 0]], np.float32)
    if coverage is None:
        hs = s - cv2.filter2D(s, -1, k4, borderType=cv2.BORDER_REFLECT)
    else:
        c = np.asarray(coverage, np.float32)
        num = cv2.filter2D(s * c[..., None], -1, k4, borderType=cv2.BORDER_REFLECT)
        den = cv2.filter2D(c, -1, k4, borderType=cv2.BORDER_REFLECT)[..., None]
        hs = s - num / np.maximum(den, 1e-3)
        hs *= (den > 0.99)  # next to the silhouette (partly uncovered neighbours) left alone
    lap = [cv2.Laplacian(np.ascontiguousarray(x @ _LUMA), cv2.CV_32F, ksize=1) for x in (s, hs, r)]
    ls, lh, lr = lap[0][ms], lap[1][ms], lap[2][mr]
    ls, lh = ls - ls.mean(), lh - lh.mean()
    # Var(∇²(s + k hs)) = a k² + b k + c + Var(∇² ref) on the skin
    a, b = float(np.mean(lh * lh)), 2.0 * float(np.mean(ls * lh))
    c = float(np.mean(ls * ls)) - float(np.var(lr))
    disc = b * b - 4 * a * c
    k = (-b + math.sqrt(disc)) / (2 * a) if a > 1e-12 and disc >= 0 else 0.0
    g = float(np.clip(1.0 + k, 1.0, max_gain))
    if g <= 1.0:
        return s.copy(), 1.0
    return np.clip(s + (g - 1.0) * hs, 0.0, 1.0), g


# ----------------------------------------------------------------------------- blending
#: erosion (3 x 3 steps) of the mask inside which the source's gradients guide the blend: OpenCV's
#: ``seamlessClone`` uses 3, and the pixels next to the border follow the destination's gradients
GUIDE_ERODE = 3


def _dst1_eigenvalues(n: int) -> np.ndarray:
    """(n - 2,) eigenvalues 2 cos(pi k / (n - 1)) - 2, k = 1..n-2, of the 1-D second difference with
    zero Dirichlet ends on n samples (the DST-I diagonalizes it)."""
    return 2 * np.cos(np.pi * np.arange(1, n - 1) / (n - 1)) - 2


def poisson_blend(src, dst, mask, *, erode: int = GUIDE_ERODE) -> np.ndarray:
    """Gradient-domain composite (Pérez et al. 2003, "normal clone"): inside the bool ``mask``
    the result has ``src``'s gradients and agrees with ``dst`` on the mask's border; outside it
    is ``dst``. ``src``, ``dst`` (H, W, 3) float [0, 1] of the same size, aligned.

    The guidance field of OpenCV's ``seamlessClone`` solved in float32: on the mask's bounding box
    R, f = dst + u with Δu = div(m ∇(src − dst)) (forward differences, m the mask eroded by
    ``erode`` px, so the pixels next to the border follow ``dst``'s own gradients) and u = 0 on R's
    border, solved exactly by the discrete sine transform (scipy.fft, DST-I) as OpenCV does; the
    same f as its 8-bit solve (which rounds the inputs and truncates the result: a one-ulp change
    of ``src`` could move it by 1.4/255), without the quantization."""
    import scipy.fft

    s = np.asarray(src, np.float32)
    d = np.asarray(dst, np.float32)
    m = np.asarray(mask, bool)
    if s.shape != d.shape or m.shape != s.shape[:2] or s.ndim != 3:
        raise BadInputError(f"src {s.shape}, dst {d.shape} and mask {m.shape} must have the same size")
    out = d.copy()
    if m.sum() < 4:
        return out
    x0, y0, bw, bh = cv2.boundingRect(m.view(np.uint8))
    if bw < 3 or bh < 3:
        return out
    box = (slice(y0, y0 + bh), slice(x0, x0 + bw))
    mc = m[box]
    # the erosion sees nothing outside the box (as OpenCV's on the mask's bounding-box view)
    guide = cv2.erode(mc.view(np.uint8), np.ones((3, 3), np.uint8), iterations=max(0, int(erode)),
                      borderType=cv2.BORDER_CONSTANT, borderValue=0) if erode > 0 else mc.view(np.uint8)
    guide = guide.astype(np.float32)[..., None]
    diff = s[box] - d[box]
    gx = np.zeros_like(diff)
    gy = np.zeros_like(diff)
    np.subtract(diff[:, 1:], diff[:, :-1], out=gx[:, :-1])
    np.subtract(diff[1:], diff[:-1], out=gy[:-1])
    gx *= guide
    gy *= guide
    # divergence (backward differences) at the interior pixels; u = 0 on the box's border
    div = gx[1:-1, 1:-1] - gx[1:-1, :-2]
    div += gy[1:-1, 1:-1]
    div -= gy[:-2, 1:-1]
    coef = scipy.fft.dstn(div, type=1, axes=(0, 1))
    coef /= (_dst1_eigenvalues(bh)[:, None] + _dst1_eigenvalues(bw)[None, :]).astype(np.float32)[..., None]
    f = d[box].copy()
    f[1:-1, 1:-1] += scipy.fft.idstn(coef, type=1, axes=(0, 1))
    np.clip(f, 0, 1, out=f)
    out[box] = np.where(mc[..., None], f, d[box])
    return out


def _mouth_frame(lips: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(centre, rotation (2, 2) whose rows are the mouth's u (corner to corner) and v axes,
    width, opening) of an inner-lip contour 60-67 (8, 2)."""
    c = lips.mean(axis=0)
    u = lips[4] - lips[0]
    width = float(np.linalg.norm(u))
    u = u / max(width, 1e-9)
    R = np.array([u, [-u[1], u[0]]])
    gap = float(np.mean([np.linalg.norm(lips[a] - lips[b]) for a, b in ((1, 7), (2, 6), (3, 5))]))
    return c, R, width, gap


def _open_fade(width: float, gap: float, closed: float) -> float:
    """0 for a lip gap up to ``closed`` x the mouth ``width``, 1 from twice that, smooth between."""
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


def _lip_arcs(lips: np.ndarray, R: np.ndarray, c: np.ndarray):
    """(upper, lower, u0, u1): the inner-lip contour 60-67 in its mouth frame (u along the corner
    line, v across it, v growing towards the lower lip) as two smooth curves v(u) through the
    points (monotone cubic, PCHIP: no overshoot between the landmarks), upper 60-64 and lower
    64-67-60, over the corners' u range [u0, u1]; None when the contour is degenerate."""
    q = (lips - c) @ R.T
    u0, u1 = float(q[0, 0]), float(q[4, 0])
    if not u1 - u0 > 1e-3:
        return None
    arcs = []
    for idx in ((0, 1, 2, 3, 4), (0, 7, 6, 5, 4)):
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


def mouth_interior(frame, driver_lips, puppet_lips, shape=None, *, inset: float = 0.9,
                   closed: float = 0.04, soft: float = 0.15,
                   lip_key: tuple[float, float] | None = (4.0, 12.0)) -> tuple[np.ndarray, np.ndarray]:
    """The driver's mouth interior moved into the puppet's mouth: (image (H, W, 3), alpha (H, W)).

    ``driver_lips``, ``puppet_lips`` (8, 2): iBUG inner-lip points 60-67 in ``frame`` px (driver)
    and output px (puppet). Both inner-lip contours are drawn as smooth curves (:func:`_lip_arcs`),
    and every puppet pixel takes the driver's pixel at the same place between the corners (along
    the corner line) and between the upper and lower lip (across it): teeth, tongue and the dark
    cavity land where they are in the driver's mouth, whatever the two mouths' shapes. Both
    coordinates are pulled towards the mouth's centre by ``inset`` (< 1: the edge samples the
    driver's interior, not its lips). Alpha: 0 outside the puppet's inner lips, rising to 1 over
    ``soft`` x the local lip gap inside them (the puppet's lips overlap the interior: no polygon
    edge), faded out as the driver's lip gap falls from 2 x ``closed`` to ``closed`` times its
    mouth width (closed lips have no interior to show). ``lip_key`` (lo, hi): the driver's own
    lips are keyed out of the interior (None: off): dlib's inner-lip points of a slightly open
    mouth sit on the lips, whose red, stretched over the puppet's opening, drew a flat red
    polygon. A pixel counts as lip unless its colour (CIELAB a, b) differs from the lips' or
    it is lighter (alpha x 0 when the larger of the two differences is <= lo, x 1 when >= hi):
    the inner lip surface has the lips' colour, only darker, while the cavity and tongue in
    shadow lose it and teeth lose it and gain light (measured on GRID clips with the Bush and
    Blair puppets: median a-b distance 3-4 on the inner lip surface of slightly open mouths,
    14-25 in open mouths with teeth).
    The lip colour is the median of the driver's frame just outside its inner-lip contour."""
    f = np.asarray(frame, np.float32)
    h, w = _shape2(f.shape if shape is None else shape)
    dp = np.asarray(driver_lips, np.float64)
    pp = np.asarray(puppet_lips, np.float64)
    if dp.shape != (8, 2) or pp.shape != (8, 2):
        raise BadInputError(f"inner lips must be (8, 2) points 60-67, got {dp.shape} and {pp.shape}")
    none = np.zeros((h, w, 3), np.float32), np.zeros((h, w), np.float32)
    if not (np.isfinite(dp).all() and np.isfinite(pp).all()):
        return none
    cd, Rd, wd, gd = _mouth_frame(dp)
    cp, Rp, wp, gp = _mouth_frame(pp)
    # closed driver lips have no interior to show (their sliver would draw a red line): fade out
    fade = _open_fade(wd, gd, closed)
    arcs_p, arcs_d = _lip_arcs(pp, Rp, cp), _lip_arcs(dp, Rd, cd)
    if fade <= 0 or arcs_p is None or arcs_d is None:
        return none
    # the puppet's mouth box (the corners and the contour's extent, plus a pixel)
    x0, y0 = (max(0, int(np.floor(v)) - 1) for v in pp.min(axis=0))
    x1, y1 = min(w, int(np.ceil(pp[:, 0].max())) + 2), min(h, int(np.ceil(pp[:, 1].max())) + 2)
    if x1 <= x0 or y1 <= y0:
        return none
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float64)
    q = np.stack([xx - cp[0], yy - cp[1]], axis=-1) @ Rp.T
    u, v = q[..., 0], q[..., 1]
    up_p, lo_p, pu0, pu1 = arcs_p
    up_d, lo_d, du0, du1 = arcs_d
    uc = np.clip(u, pu0, pu1)
    a, b = up_p(uc), lo_p(uc)
    gap = np.maximum(b - a, 0.0)
    # depth inside the lips (px): to the nearer lip across the mouth, to the nearer corner along it
    depth = np.minimum(np.minimum(v - a, b - v), np.minimum(u - pu0, pu1 - u))
    # one ramp width for the whole mouth (its widest gap's): the thin parts towards the corners
    # fade instead of ending in hard tips
    width = max(soft * float(gap.max()), 1.0)
    # a pixel's centre half a pixel inside the lips is half covered (as an anti-aliased polygon's
    # edge); an opening thinner than a pixel is covered by its thickness (closed lips: nothing)
    r = np.clip((depth + 0.5) / width, 0.0, 1.0)
    alpha = np.zeros((h, w), np.float32)
    alpha[y0:y1, x0:x1] = smoothstep(r) * np.clip(gap, 0.0, 1.0) * fade
    if alpha.max() <= 0:
        return none
    # the same place in the driver's mouth: fraction along the corner line and across the gap
    su = 0.5 + inset * ((uc - pu0) / (pu1 - pu0) - 0.5)
    sv = 0.5 + inset * (np.clip((v - a) / np.maximum(gap, 1e-6), 0.0, 1.0) - 0.5)
    ud = du0 + su * (du1 - du0)
    vd = up_d(ud) + sv * (lo_d(ud) - up_d(ud))
    xy = np.stack([ud, vd], axis=-1) @ Rd + cd
    warped = cv2.remap(f, xy[..., 0].astype(np.float32), xy[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE)
    if lip_key is not None:
        # the driver's lips: just above its upper and below its lower inner-lip curve, middle 60 %
        us = du0 + np.linspace(0.2, 0.8, 9) * (du1 - du0)
        off = 0.04 * wd + 1.0
        ring = np.concatenate([np.stack([us, up_d(us) - off], -1), np.stack([us, lo_d(us) + off], -1)]) @ Rd + cd
        lip = cv2.remap(f, ring[None, :, 0].astype(np.float32), ring[None, :, 1].astype(np.float32), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
        lip_lab = np.median(_lab(lip)[0], axis=0)
        lab = _lab(warped)
        unlike = np.maximum(np.linalg.norm(lab[..., 1:] - lip_lab[1:], axis=-1), lab[..., 0] - lip_lab[0])
        lo, hi = lip_key
        k = np.clip((unlike - lo) / max(hi - lo, 1e-6), 0.0, 1.0)
        k = smoothstep(k).astype(np.float32)
        # smoothed over the mouth opening only (normalized convolution): the box's pixels outside
        # the lips sample the driver's lips and would darken a thin opening's key
        inside = (alpha[y0:y1, x0:x1] > 0).astype(np.float32)
        k = cv2.GaussianBlur(k * inside, (0, 0), 1.0) / np.maximum(cv2.GaussianBlur(inside, (0, 0), 1.0), 1e-6)
        alpha[y0:y1, x0:x1] *= np.clip(k, 0.0, 1.0)
    img = np.zeros((h, w, 3), np.float32)
    img[y0:y1, x0:x1] = warped
    return img, alpha


def mouth_closure(inner_lips, closed: float = 0.04) -> float:
    """How closed a mouth is, from its inner-lip points 60-67 (8, 2): 1 when the lip gap is at most
    ``closed`` x the mouth width, 0 from twice that (smooth in between): the complement of
    :func:`mouth_interior`'s fade."""
    p = np.asarray(inner_lips, np.float64)
    if p.shape != (8, 2) or not np.isfinite(p).all():
        return 0.0
    _, _, wd, gd = _mouth_frame(p)
    return 1.0 - _open_fade(wd, gd, closed)


def fill_mouth_interior(texture, inner_lips, closure: float) -> np.ndarray:
    """``texture`` (H, W, 3) float with the inside of its inner-lip contour ``inner_lips`` (8, 2),
    grown by a pixel, filled from the lips around it (OpenCV's Telea inpainting), mixed in by
    ``closure`` in [0, 1] (:func:`mouth_closure` of the frame's mouth). A persona whose photos
    mostly smile has teeth between its average's inner lips; lips that close over them leave a
    sub-pixel sliver that rendered as a white strip between dark lines (read as an open mouth)."""
    t = np.asarray(texture, np.float32)
    c = float(np.clip(closure, 0.0, 1.0))
    p = np.asarray(inner_lips, np.float64)
    if c <= 0 or p.shape != (8, 2) or not np.isfinite(p).all():
        return t
    h, w = _shape2(t.shape)
    x0, y0 = (max(0, int(np.floor(v)) - 4) for v in p.min(axis=0))
    x1, y1 = min(w, int(np.ceil(p[:, 0].max())) + 5), min(h, int(np.ceil(p[:, 1].max())) + 5)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return t
    roi = t[y0:y1, x0:x1]
    hole = polygon_mask(p - [x0, y0], roi.shape[:2])
    hole = cv2.dilate((hole > 0.25).astype(np.uint8), np.ones((3, 3), np.uint8))
    if not hole.any():
        return t
    u8 = (np.clip(roi, 0, 1) * 255 + 0.5).astype(np.uint8)
    filled = cv2.inpaint(u8, hole, 2, cv2.INPAINT_TELEA).astype(np.float32) / 255
    a = c * cv2.GaussianBlur(hole.astype(np.float32), (0, 0), 0.7)[..., None]
    out = t.copy()
    out[y0:y1, x0:x1] = roi + a * (filled - roi)
    return out


# ----------------------------------------------------------------------------- measure
def boundary_color_step(image, mask, *, band: float = 3.0, gap: float = 1.0, sectors: int = 16,
                        min_pixels: int = 3) -> tuple[float, np.ndarray]:
    """Colour step across the edge of the bool ``mask`` on ``image`` (H, W, 3) sRGB [0, 1]:
    the CIE76 ΔE (CIELAB) between the mean colours of the band just inside the edge
    (``gap`` < distance <= ``gap + band`` px) and the band just outside, taken separately in
    ``sectors`` angular sectors around the mask's centroid (a global mean would let a too-bright
    forehead cancel a too-dark jaw). Returns (mean over the sectors where both bands have
    >= ``min_pixels`` pixels, per-sector ΔE (NaN where not measured))."""
    img = np.asarray(image, np.float32)
    m = np.asarray(mask, bool)
    if img.shape[:2] != m.shape:
        raise BadInputError(f"image {img.shape} and mask {m.shape} must have the same size")
    steps = np.full(sectors, np.nan)
    if m.sum() < 4 or m.all():
        return float("nan"), steps
    din = cv2.distanceTransform(np.pad(m, 1).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    dout = cv2.distanceTransform(np.pad(~m, 1, constant_values=True).astype(np.uint8), cv2.DIST_L2,
                                 cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    inner = m & (din > gap) & (din <= gap + band)
    outer = ~m & (dout > gap) & (dout <= gap + band)
    ys, xs = np.nonzero(m)
    cy, cx = ys.mean(), xs.mean()
    yy, xx = np.mgrid[0:m.shape[0], 0:m.shape[1]]
    sec = (((np.arctan2(yy - cy, xx - cx) + math.pi) / (2 * math.pi)) * sectors).astype(int) % sectors
    lab = _lab(img)
    for k in range(sectors):
        a, b = inner & (sec == k), outer & (sec == k)
        if a.sum() >= min_pixels and b.sum() >= min_pixels:
            steps[k] = float(np.linalg.norm(lab[a].mean(axis=0) - lab[b].mean(axis=0)))
    ok = np.isfinite(steps)
    return (float(steps[ok].mean()) if ok.any() else float("nan")), steps


# ----------------------------------------------------------------------------- pipeline
LIGHTINGS = ("stats", "sh", "none")
#: skin colour, occluders and the low-frequency colour field are worked out on the face's box
#: shrunk to about this many px between the outer eye corners
WORK_IOD = 16.0
#: the inward feather is this many times wider with ``colour="persona"`` (no Poisson seam there)
PERSONA_FEATHER = 3.0


@dataclass(frozen=True)
class CompositeParams:
    """How the puppet is put into the driver's frame.

    lighting: the colour statistics ("stats", default), also the driver's first-order SH
    lighting ("sh"; ``sh_strength`` the exponent of the shading ratio) or nothing ("none").
    On GRID's frontally lit clips the SH ratio mostly moved the albedo of the persona's average
    (stubble, lips, the collection's top light) into the shading: a beard-like darkening
    around the mouth (bench contact sheets), so it is not the default. normal_smoothing:
    Gaussian sigma of the normals before the SH fit and relighting, as a fraction of the
    eye-corner distance; colour: the puppet's skin takes the driver's colour ("driver") or keeps
    the persona's and takes only the lighting ("persona"; no Poisson blending then, its membrane
    would bring the driver's tone back); colour_sigma: the scale below which the colour is the
    driver's, as a fraction of the eye-corner distance, and colour_gain: the bounds of the
    lightness-detail gain (:func:`transfer_skin_colour`); lip_colour: with colour "driver" the
    lips take the driver's lips' colour (:func:`lip_weights`), not the skin's; eye_colour: the
    eyeballs keep the persona's colour (:func:`eye_weights`). Chosen by the cheek ΔE (CIELAB) to the
    driver's own cheeks over 6 personas x 6 GRID clips (worst run, skin-only masks: mean shift 19,
    MKL 22 (and pink lips), per-channel histogram matching 27, smooth field at 0.4 / 0.25 / 0.15 /
    0.10 / 0.08 eye distances 19 / 16 / 12 / 7.8 / 6.2; 0.12 to 0.08 look alike at 100 %; with the
    sharper eye and mouth textures 0.08 gave 9.1 on a dark persona over a pale driver, 0.06 7.2,
    alike at 100 %) and by looking at the eyes: a gain from the skins' high-pass spreads (0.5 on
    a dark persona over a pale driver) greyed the irises; an upper bound of 1.5 (a dark persona's
    skin is ~1.8x darker in L* than a pale driver's) blackened the eye sockets and nostrils and
    turned the lips white, 1.2 keeps them a face's (cheek ΔE 7.4 -> 6.7 on that pair);
    lid_colour: the lids round the eyes take the driver's lid lightness at this strength
    (:func:`lid_weights`, 0: off, the default): a dark persona's dark lids looked like shadow rings
    on pale drivers, and at 1 Williams' eye openness rose (0.83-0.90 -> 0.84-0.95 of the driver's)
    and Bush/sbwe5n's mouth slope came into range (1.32 -> 1.20), but Chavez's deep-set eyes read
    less open (pwij3p 0.83 -> 0.79, at 0.5 0.80) and Koizumi/id2 came out 80 % closer to the
    persona (100 %); occlusion: keep the driver's occluders in front (:func:`occlusion_mask`); sharpen: the
    puppet's fine detail is raised towards the driver's frame's, at most by this gain (1: off;
    :func:`match_sharpness`); poisson:
    gradient-domain blending at the border; feather: width of the inward feather as a fraction of the eye-corner distance;
    erode: the driver's outline is shrunk by this fraction (the face-oval vertices sit on the
    silhouette, where skin meets hair or background); mouth: draw the driver's mouth interior
    inside the puppet's lips.
    """

    lighting: str = "stats"
    sh_strength: float = 1.0
    normal_smoothing: float = 0.05
    colour: str = "driver"
    colour_sigma: float = 0.06
    colour_gain: tuple[float, float] = (2 / 3, 1.2)
    lip_colour: bool = True
    lid_colour: float = 0.0
    eye_colour: bool = True
    occlusion: bool = True
    sharpen: float = 2.5
    poisson: bool = True
    feather: float = 0.06
    erode: float = 0.03
    mouth: bool = True


def composite_face(frame, puppet, coverage, normals, *, driver_oval, driver_points68, puppet_lips=None,
                   driver_normals=None, params: CompositeParams = CompositeParams()) -> tuple[np.ndarray, np.ndarray]:
    """The puppet composited into the driver's frame: (image (H, W, 3), alpha (H, W)).

    ``frame`` (H, W, 3) the driver's frame; ``puppet`` (H, W, 3) the rendered puppet,
    ``coverage`` (H, W) its anti-aliased coverage, ``normals`` (H, W, 3) its unit camera-space
    normals (needed for ``lighting="sh"`` only, else may be None); ``driver_oval`` (K, 2) the
    driver's face outline and ``driver_points68`` its
    landmarks (frame px); ``puppet_lips`` (8, 2) the puppet's inner lips (output px) or None;
    ``driver_normals`` (H, W, 3) the driver's own face normals (its lighting is fitted with them;
    default: the puppet's normals).
    All work happens in the face's bounding box."""
    if params.lighting not in LIGHTINGS:
        raise BadInputError(f"unknown lighting {params.lighting!r}: use one of {', '.join(LIGHTINGS)}")
    if params.colour not in COLOURS:
        raise BadInputError(f"unknown colour {params.colour!r}: use one of {', '.join(COLOURS)}")
    frame = np.asarray(frame, np.float32)
    H, W = frame.shape[:2]
    p68 = np.asarray(driver_points68, np.float64)
    iod = float(np.linalg.norm(p68[36] - p68[45]))
    outline = polygon_mask(driver_oval, (H, W)) > 0.5
    k = int(round(params.erode * iod))
    if k > 0:
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * k + 1,) * 2)
        outline = cv2.erode(outline.astype(np.uint8), disc) > 0
    region = outline & (np.asarray(coverage) > 0.5)
    if np.count_nonzero(region) < 16:
        return frame.copy(), np.zeros((H, W), np.float32)
    bx, by, bw, bh = cv2.boundingRect(region.view(np.uint8))
    pad = 3 + int(round(0.1 * iod))
    y0, y1 = max(0, by - pad), min(H, by + bh + pad)
    x0, x1 = max(0, bx - pad), min(W, bx + bw + pad)
    box = (slice(y0, y1), slice(x0, x1))
    fr, pu, rg = frame[box], np.asarray(puppet, np.float32)[box], region[box]
    nr = None if normals is None else np.asarray(normals, np.float32)[box]
    skin = None  # the SH fit's skin (full size), made only for it
    if params.lighting == "sh":
        skin = rg & ~feature_mask(p68 - [x0, y0], rg.shape)
        skin = cv2.erode(skin.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        if skin.sum() < 16:
            skin = rg
    # skin-only colour of both faces (the driver's fringe, stubble, shadows and the persona's
    # darker brows and lids must not set the colour), and what lies over the driver's face
    # (on the box shrunk to ~WORK_IOD px between the eye corners: both are low-frequency)
    ks = max(1, int(iod // WORK_IOD))
    bh, bw = rg.shape
    small = (max(1, round(bw / ks)), max(1, round(bh / ks)))

    def shrunk(x):
        return cv2.resize(np.asarray(x, np.float32), small, interpolation=cv2.INTER_AREA) if ks > 1 else x

    p_s = (p68 - [x0, y0] + 0.5) * [small[0] / bw, small[1] / bh] - 0.5
    rg_s = rg if ks == 1 else shrunk(rg) > 0.5
    drv_skin, feats = skin_pixels(shrunk(fr), p_s, rg_s)
    skin_s = rg_s & ~feats if (rg_s & ~feats).sum() >= 16 else rg_s
    occ = None
    if params.occlusion:
        occ = occlusion_mask(rg_s, drv_skin, feats, p_s)
        occ = (cv2.resize(occ, (bw, bh), interpolation=cv2.INTER_LINEAR) if ks > 1 else occ) * rg
    # the persona's average texture has no hair or cast shadows on its face (they average out):
    # its features are left out, the trimmed statistics do the rest
    pup_skin = rg_s & ~feats
    drv_skin = skin_s if drv_skin is None or drv_skin.sum() < 16 else drv_skin
    pup_skin = skin_s if pup_skin is None or pup_skin.sum() < 16 else pup_skin
    out = pu
    if params.lighting == "sh":
        if nr is None:
            raise BadInputError("lighting='sh' needs the puppet's normals")
        # low-frequency lighting: normals smoothed over ~5 % of the eye distance (the grid mesh's
        # creases at nostrils and lip corners would otherwise print as bright lines)
        sig = max(1.0, params.normal_smoothing * iod)

        def smooth(n, valid):
            # a visible surface faces the camera (n_z < 0): folds of a deformed mesh must not flip it
            n = np.where(n[..., 2:3] > 0, -n, n) * valid[..., None]
            wgt = cv2.GaussianBlur(valid.astype(np.float32), (0, 0), sig)[..., None]
            n = cv2.GaussianBlur(n, (0, 0), sig) / np.maximum(wgt, 1e-3)
            return n / np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-6)

        nr = smooth(nr, rg)
        nd = nr
        if driver_normals is not None:
            dn = np.asarray(driver_normals, np.float32)[box]
            valid = np.linalg.norm(dn, axis=2) > 0.5
            if (valid & skin).sum() > 0.5 * skin.sum():
                nd = smooth(dn, valid)
        # lighting from luminance only (colour comes from the statistics below): per-channel fits
        # turn red lips and stubble under the mouth into a colour cast of the downward normals
        lin_p, lin_d = srgb_to_linear(pu), srgb_to_linear(fr)
        lum_p, lum_d = (lin_p @ _LUMA)[..., None], (lin_d @ _LUMA)[..., None]
        lp = fit_sh_lighting(lum_p, nr, skin)
        ld = fit_sh_lighting(lum_d, nd, skin)
        ratio = relight(np.ones_like(lum_p), nr, lp, ld) ** params.sh_strength
        out = linear_to_srgb(lin_p * ratio)
    if params.lighting in ("sh", "stats"):
        out = transfer_skin_colour(out, fr, pup_skin, drv_skin, sigma=max(1.0, params.colour_sigma * iod),
                                   gain=params.colour_gain, colour=params.colour, shrink=ks,
                                   lips=lip_weights(p68 - [x0, y0], rg.shape) if params.lip_colour else None,
                                   lids=_scaled(lid_weights(p68 - [x0, y0], rg.shape), params.lid_colour)
                                   if params.lid_colour > 0 else None,
                                   keep=eye_weights(p68 - [x0, y0], rg.shape) if params.eye_colour else None)
    if params.sharpen > 1:
        # after the colour transfer: a dark persona's detail is small in sRGB until it takes a pale
        # driver's tone (measured before, Williams' puppets were sharpened to 2x the driver's detail).
        # Skin of both at full size: the driver's landmarks (the puppet sits there), features cut out,
        # and only what has the driver's skin colour (its hair, fringe, glasses and the background
        # at the outline would set a far higher target)
        skin_full = rg & ~feature_mask(p68 - [x0, y0], rg.shape)
        colour_skin = cv2.resize(drv_skin.astype(np.uint8), (bw, bh), interpolation=cv2.INTER_NEAREST) > 0 \
            if ks > 1 else drv_skin
        if (skin_full & colour_skin).sum() >= 64:
            skin_full = skin_full & colour_skin
        out, _ = match_sharpness(out, fr, skin_full, skin_full, max_gain=params.sharpen,
                                 coverage=np.asarray(coverage, np.float32)[box])
    if params.poisson and params.colour == "driver":  # the membrane would bring the driver's tone back
        out = poisson_blend(out, fr, rg)
    if params.mouth and puppet_lips is not None:
        mi, ma = mouth_interior(fr, p68[list(INNER_LIPS)] - [x0, y0], np.asarray(puppet_lips) - [x0, y0], rg.shape)
        ma = ma * rg
        out = _mix(ma, mi, out)
    # the persona's own skin tone meets the driver's at the outline: a wider ramp than the
    # gradient-domain seam needs
    feather = params.feather * (PERSONA_FEATHER if params.colour == "persona" else 1.0)
    alpha = inner_feather(rg, max(1.0, feather * iod))
    if occ is not None:  # the driver's occluders stay in front of the puppet
        alpha = alpha * (1 - occ)
    res = frame.copy()
    res[box] = _mix(alpha, out, fr)
    full = np.zeros((H, W), np.float32)
    full[box] = alpha
    return res, full
