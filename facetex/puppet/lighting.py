"""The puppet's lighting and skin colour in the driver's frame (:mod:`facetex.puppet.composite`,
"lighting" and "skin colour"): linear light, first-order spherical harmonics, Lab statistics and the
robust low-frequency skin colour transfer."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import BadInputError
from ..io import linear_to_srgb, srgb_to_linear  # re-exported: the lighting works in linear light
from ._pixels import _pixels, _shape2, _shift

__all__ = [
    "srgb_to_linear",
    "linear_to_srgb",
    "sh_basis",
    "fit_sh_lighting",
    "sh_shading",
    "relight",
    "match_color_statistics",
    "skin_low_pass",
    "COLOURS",
    "transfer_skin_colour",
    "NOSTRIL_PERCENTILE",
    "floor_nostrils",
]


# ----------------------------------------------------------------------------- lighting
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
def _linear(rgb) -> np.ndarray:
    """Linear light of sRGB clipped to [0, 1]."""
    return srgb_to_linear(np.clip(np.asarray(rgb, np.float32), 0, 1))


def _lab(rgb):
    """CIELAB (L* 0..100) of sRGB [0, 1]: OpenCV's conversion of the linear-light values. Its own
    float sRGB path interpolates a 3-D table: a* and b* move in steps of up to 0.4 for a 1e-5 change
    of the input (0.6 off the exact values), which the skin colour transfer turned into 1.2/255
    jumps of single pixels between two puppets 0.01/255 apart; this one is continuous (within 0.03
    of the exact conversion) at 1.4x its cost."""
    return cv2.cvtColor(_linear(rgb), cv2.COLOR_LRGB2Lab)


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


#: the percentile of the persona's lip lightness that the lips' highlight gain brings to the lip
#: ceiling (:func:`transfer_skin_colour`)
LIP_SPREAD_PERCENTILE = 90.0


def _eye_skin_shading(out, detail, src_lab, ref_lab, field, src_light, g, eye_skin, src_skin, ref_skin,
                      shrink: int, sigma: float, strength: float, trim: float = 6.0) -> None:
    """``eye_skin`` of :func:`transfer_skin_colour`, in place on ``out`` = g src + ``field`` (H, W, 3
    CIELAB; ``field`` = R - g S at full size) and the lightness ``detail`` = src L - ``src_light``
    (S's L at full size): in the eye zone's box R and S are replaced by the skins' normalized low
    passes (Gaussian ``sigma``) with the zone counted as skin."""
    zone_weight, eyes = eye_skin() if callable(eye_skin) else eye_skin
    zone_weight = np.asarray(zone_weight, np.float32)
    weight = zone_weight * strength
    ys, xs = np.nonzero(weight > 0.01)
    if len(ys) == 0:
        return
    h, w = weight.shape
    pad = int(3 * sigma) + 2
    box = (slice(max(0, ys.min() - pad), min(h, ys.max() + pad + 1)),
           slice(max(0, xs.min() - pad), min(w, xs.max() + pad + 1)))
    zone = (zone_weight[box] > 0.05) & ~np.asarray(eyes, bool)[box]

    def skin(m):  # the masks are given at the fields' (shrunk) size
        m = np.asarray(m, np.uint8)
        return ((cv2.resize(m, (w, h), interpolation=cv2.INTER_NEAREST) if shrink > 1 else m)[box] > 0) | zone

    sf, _ = skin_low_pass(src_lab[box], skin(src_skin), sigma, trim=trim)
    rf, _ = skin_low_pass(ref_lab[box], skin(ref_skin), sigma, trim=trim)
    wb, ob = weight[box], out[box]
    for c in range(3):
        ob[..., c] += wb * (rf[..., c] - g[c] * sf[..., c] - field[box][..., c])
    if detail is not None:  # the persona's shading under its skin field is no longer detail
        detail[box] -= wb * (sf[..., 0] - src_light[box])


def transfer_skin_colour(src, ref, src_skin, ref_skin, *, sigma: float, gain=(2 / 3, 1.2), colour: str = "driver",
                         light_limits=(0.5, 2.0), shrink: int = 1, lips=None, lids=None, keep=None,
                         lip_parts=(), lip_ceiling: float | None = None, keep_chroma: bool = True,
                         keep_dark=None, brows=None, brow_gain: float = 2.0, chroma_gain=(1.0, 1.0),
                         highlight_knee: float | None = None, shadows=None,
                         shadow_knee: float = 6.0, eye_skin=None, eye_skin_sigma: float = 4.0,
                         fine=None) -> np.ndarray:
    """``src`` (H, W, 3) sRGB with the low-frequency colour of ``ref`` (the same size, aligned),
    measured on skin pixels only (bool ``src_skin``, ``ref_skin``), the detail of ``src`` kept.

    In CIELAB, with low-passes S, R of the two skins and their medians s, r
    (:func:`skin_low_pass`, Gaussian ``sigma`` px): ``colour="driver"``:
    out = R + (g, c, c) (src − S), the lightness detail gain g = r_L / s_L clipped to ``gain``
    (a dark persona's iris and lids keep their contrast on a pale driver, a pale persona's pores
    do not turn coarse on a dark one); the persona's own shading and blotches below ~``sigma``
    become the driver's, so they cannot be amplified into bruises.
    ``chroma_gain`` (colour "driver"): the a*, b* detail's gain c is the ratio of the skins' median
    chroma (sqrt(a*^2 + b*^2), driver over persona) clipped to these bounds (default (1, 1): 1):
    a saturated persona's dark features (lash lines, brows, lid shadows), less saturated than her
    skin, turned blue or teal on a pale, less saturated driver (their chroma offset from her skin
    crossed neutral). ``highlight_knee`` (colour "driver", L*, or an (H, W) map of it; None: off):
    lightness detail above the persona's skin field, d > 0, is compressed to knee x tanh(d / knee)
    before its gain: a
    persona's specular highlights (a shiny brow ridge or nose in her photos' light) were white
    bands on a pale driver; their a*, b* detail is cut in the same proportion (a highlight is white
    light: with its lightness alone cut, Williams' brow ridge stayed a grey band, a* 5 against the
    forehead's 11, on FRL 022). ``shadows`` (colour "driver"): weight (H, W) in [0, 1], a function
    returning it, or None: there,
    on a darker persona than the driver, the lightness detail below the persona's skin field, d < 0,
    is compressed to -``shadow_knee`` x tanh(-d / ``shadow_knee``) before its gain (and before
    ``keep_dark``'s), in full from a skins' lightness ratio at ``gain``'s upper bound, not at all
    from a ratio of 1 down (linear between): a persona's dark under-eye circles and cheek shading
    (Serena Williams' photos: -10 to -22 L* under her skin field round a shiny cheekbone) were black
    eyes and bruises on a pale driver; like ``brows``, a function returning the weight is called
    only then. ``eye_skin`` (colour "driver"): (weight (H, W) in [0, 1], bool (H, W) eyeballs) or a
    function returning them (called only when used), or None: there, on a darker persona than the
    driver (in full and not at all as for ``shadows``), the skins' low-frequency colour is also
    measured on the skin round the eyes (the skin masks plus the weight's zone minus the eyeballs;
    Gaussian ``eye_skin_sigma`` px, outliers clipped at 6 MADs, not 3) and the persona's shading at
    that scale is replaced by the driver's: the skin masks leave out a margin round the eyes (and the
    skin model the darkest skin), so both fields there were interpolated from the cheeks, and a dark
    persona's under-eye circles (in Williams' photos 18 L* under her cheeks) stayed as a grey-brown
    mask across a pale driver's eyes. ``colour="persona"``: only the lighting moves: linear-light R, G, B x
    (Y(R_L) / Y(r_L)) / (Y(S_L) / Y(s_L)), the driver's low-frequency luminance ratio over the
    persona's (Y(L*) the CIE luminance, the ratio clipped to ``light_limits``), the persona's
    chromaticity kept.
    ``fine``: (weight (H, W) in [0, 1] at the fields' size, sigma px) or None: where the weight is,
    both fields are mixed towards their low passes at that (finer) sigma.
    ``shrink`` > 1: the low-frequency fields are computed on both images shrunk by that factor
    (area average; ``src_skin`` and ``ref_skin`` are given at the shrunk size) and resized back
    (bilinear): the same fields at a fraction of the cost.
    ``lips`` (colour "driver"): (weight (H, W) in [0, 1], bool (H, W) lip pixels of both images)
    or (weight, ``ref``'s lip pixels, ``src``'s lip pixels), or None: where the weight is 1 the
    low-frequency colour is the lips' own, out = r' + (g, 1, 1) (src − s'), r' and s' the two lip
    medians: lips are not skin, and the skin's field gave a
    dark persona's lips, lighter than her skin, a pale driver's skin tone plus that difference
    (white lips; a pale driver's lips are darker than her skin). ``keep`` (colour "driver"):
    weight (H, W) in [0, 1] or None: where it is 1 ``src`` is kept as it is (the eyeballs,
    :func:`~facetex.puppet.eyes.eye_weights`: iris and whites are not skin; with the skin's field and the bounded
    lightness gain a dark persona's brown irises turned grey on a pale driver); ``keep_chroma``
    False: only its lightness is kept, its a*, b* take the transfer (the frame's white balance: kept
    whole, a pale persona's eyeballs were blue-grey patches in an orange frame). ``keep_dark``
    (colour "driver"): weight (H, W) in [0, 1] or None, applied before ``keep`` (the lids' rims
    round the eyeballs): where it is 1, on a darker persona than the driver (the skins' lightness
    ratio above ``gain``'s upper bound) the lightness detail darker than ``src``'s skin field takes
    that ratio clipped to ``brow_gain``, as the brows (a dark persona's lash lines stay dark on a
    pale driver; keeping their lightness as it was drew her whole lids, darker than her skin, as
    dark maroon almonds round a pale driver's eyes), otherwise ``src``'s lightness is kept where it
    is darker than the transfer's, never where lighter (a pale persona's lid highlights do not stay
    pale on a dark driver). ``brows`` (colour "driver"): weight
    (H, W) in [0, 1], a function returning it (drawn only when used) or None: there the lightness
    detail darker than ``src``'s skin field takes the skins' lightness ratio clipped to
    ``brow_gain`` instead of ``gain``'s upper bound (brows are hair: a dark persona's brows, darker
    than her skin by less than a pale driver's are than his, came out faint; only where that ratio
    is above the bound, i.e. a darker persona on a paler driver). ``lids`` (colour
    "driver"): the same as ``lips`` for the skin round the eyes (:func:`~facetex.puppet.eyes.lid_weights`): a dark
    persona's lids, darker than her skin, kept that difference on a pale driver as dark rings.
    ``lip_parts``: more regions like ``lips``, applied after it in order (the upper and lower
    lip of an open mouth, :func:`~facetex.puppet.mouth.open_lip_weights`). ``lip_ceiling``
    (with ``lips``): the lips' lightness at most ``ref``'s lip median + this (L*, 0..100): a
    persona whose photos smile has teeth at its texture's inner lips, lighter than any lip, and
    the kept detail drew them as a white rim on the puppet's lips. Above the lips' median their
    lightness detail takes the gain that brings the persona's lip 90th percentile to the ceiling
    (at most g): clipped alone, a dark persona's lower lip, much lighter than her upper lip, was a
    flat patch with a hard edge on a pale driver.
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
    lab_s, lab_r = _lab(s_small), _lab(r_small)
    sa, ca = skin_low_pass(lab_s, sm, sigma / k)
    sb, cb = skin_low_pass(lab_r, rm, sigma / k)
    if fine is not None:
        fw, fs = fine
        fw = np.asarray(fw, np.float32)[..., None]
        sa = sa + fw * (skin_low_pass(lab_s, sm, fs / k)[0] - sa)
        sb = sb + fw * (skin_low_pass(lab_r, rm, fs / k)[0] - sb)

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
    # persona's iris, lids and pores keep their contrast on a pale driver; chroma detail scales with
    # the skins' chroma. out = R + (g_L, g_c, g_c) (src - S) = g src + field
    ratio = float(cb[0]) / max(float(ca[0]), 1.0)
    chroma = float(np.hypot(cb[1], cb[2])) / max(float(np.hypot(ca[1], ca[2])), 1.0)
    g = np.float32([np.clip(ratio, *gain), *[np.clip(chroma, *chroma_gain)] * 2])
    field = np.empty(sa.shape, np.float32)
    for c in range(3):
        field[..., c] = sb[..., c] - g[c] * sa[..., c]
    field = full(field)
    a = _lab(src)
    out = np.empty(a.shape, np.float32)
    for c in range(3):
        out[..., c] = g[c] * a[..., c] + field[..., c]
    # a darker persona on a paler driver: detail darker than the persona's skin (brows, lash lines,
    # lid creases) takes the skins' lightness ratio, bounded by brow_gain, not the gain's bound
    gb = float(np.clip(ratio, gain[0], max(brow_gain, gain[1])))
    ratio_dark = gb > g[0] and (keep_dark is not None or brows is not None)
    # the shadow knee only for a darker persona than the driver (fully from the gain's upper bound):
    # on a paler or like-toned driver the shading is the persona's (Blair's folds on a side-lit GRID
    # speaker read as his on 96 % of frames, 84 % compressed)
    darker = float(np.clip((ratio - 1.0) / max(gain[1] - 1.0, 1e-6), 0.0, 1.0))
    strength = darker if shadows is not None else 0.0
    eye_strength = darker if eye_skin is not None else 0.0
    # the lightness detail over the persona's skin field (the knees' and the dark detail's)
    # the persona's skin field at full size (one resize of its three channels)
    s_full = full(sa) if (highlight_knee is not None or ratio_dark or strength > 0 or eye_strength > 0) else None
    s_light = None if s_full is None else s_full[..., 0]
    detail = None if s_light is None else a[..., 0] - s_light
    if highlight_knee is not None:
        highlight_knee = np.asarray(highlight_knee, np.float32)
        up = np.maximum(detail, 0.0)
        cut = up - highlight_knee * np.tanh(up / highlight_knee)
        out[..., 0] -= g[0] * cut
        # a highlight is white light: its chroma deficit is cut in the same proportion as its lightness
        frac = cut / np.maximum(up, 1e-3)
        for c in (1, 2):
            out[..., c] -= g[c] * frac * (a[..., c] - s_full[..., c])
    if strength > 0:
        down = np.maximum(-detail, 0.0)
        ws = np.asarray(shadows() if callable(shadows) else shadows, np.float32)
        cut = strength * ws * (down - shadow_knee * np.tanh(down / shadow_knee))
        out[..., 0] += g[0] * cut
        detail = detail + cut  # the lid rims' darker gain below (keep_dark) sees the compressed detail
    ref_lab = None
    if eye_strength > 0:
        ref_lab = _lab(ref)
        _eye_skin_shading(out, detail, a, ref_lab, field, s_light, g, eye_skin, sm, rm, k, eye_skin_sigma,
                          eye_strength)
    ceiling = None
    g_light = g[0]  # the lips' gain for lightness detail above their median
    for region in (lips, *lip_parts, lids):
        if region is None:
            continue
        wl, lm = np.asarray(region[0], np.float32), np.asarray(region[1], bool)
        sl = np.asarray(region[2], bool) if len(region) > 2 else lm
        if lm.sum() >= 8 and sl.sum() >= 8 and wl.max() > 0:
            ref_lab = _lab(ref) if ref_lab is None else ref_lab
            med = np.median(_pixels(ref_lab, lm), axis=0)
            own_px = _pixels(a, sl)
            own = np.median(own_px, axis=0)
            if region is lips and lip_ceiling is not None:
                ceiling = (wl, float(med[0]) + float(lip_ceiling))
                # lightness above the lips' median scaled so that their upper percentile meets the
                # ceiling: clipped alone, a persona whose lower lip is much lighter than her upper
                # lip (a dark persona on a pale driver) got a flat pink lower lip with a hard edge
                spread = float(np.percentile(own_px[:, 0], LIP_SPREAD_PERCENTILE) - own[0])
                g_light = min(float(g[0]), float(lip_ceiling) / max(spread, 1e-6))
            d = a - own
            gl = np.where(d[..., 0] > 0, g_light, g[0]) if region is not lids and g_light != g[0] else g[0]
            out[..., 0] += wl * (med[0] + gl * d[..., 0] - out[..., 0])
            for c in (1, 2):
                out[..., c] += wl * (med[c] + g[c] * d[..., c] - out[..., c])
    if ceiling is not None:
        wl, top = ceiling
        out[..., 0] -= wl * np.maximum(out[..., 0] - top, 0.0)
    dark = np.minimum(detail, 0.0) if ratio_dark else None
    if keep_dark is not None:
        kd = np.asarray(keep_dark, np.float32)
        out[..., 0] += kd * ((gb - g[0]) * dark if dark is not None else np.minimum(a[..., 0] - out[..., 0], 0.0))
    if brows is not None and dark is not None:
        out[..., 0] += np.asarray(brows() if callable(brows) else brows, np.float32) * (gb - g[0]) * dark
    if keep is not None:
        k = np.asarray(keep, np.float32)[..., None]
        n = 3 if keep_chroma else 1
        out[..., :n] += k * (a[..., :n] - out[..., :n])
    return _rgb(out)


#: the driver's nostrils' darkness: this percentile of L* on its lower nose
NOSTRIL_PERCENTILE = 3.0


def _nonzero_box(mask: np.ndarray) -> tuple[slice, slice]:
    """(rows, columns) slices of the bounding box of a 2-D mask's nonzero pixels (some must be)."""
    ys, xs = np.nonzero(mask)
    return slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1)


def floor_nostrils(src, ref, src_nose, ref_nose, *, knee: float = 6.0,
                   percentile: float = NOSTRIL_PERCENTILE) -> np.ndarray:
    """``src`` (H, W, 3) sRGB with its lower nose no darker than ``ref``'s nostrils, softly:
    f = the ``percentile`` of L* on ``ref``'s bool ``ref_nose`` (the driver's frame: how dark the
    deepest shadow under a nose is in its light); where ``src_nose`` (weight (H, W) in [0, 1])
    is darker, L* < f, it becomes f − ``knee`` log(1 + (f − L*) / ``knee``) (its shading kept,
    compressed, not cut flat: a tanh knee drew flat brown cut-outs) and its a*, b* move to the
    mean of ``ref``'s nostril pixels (its nose at or below f) by 1 − exp(−(f − L*) / ``knee``).
    A persona whose photos' nostrils are black (Serena Williams: L* 1-3 in her
    texture, neutral grey in a*, b*) drew black holes with a blue cast under the driver's
    softer light (its nostrils L* 27-39). Unchanged where ``src`` is at f or lighter, or when
    either mask has fewer than 8 pixels. Written here: no library bounds a region's shadows by
    another image's."""
    s = np.asarray(src, np.float32)
    w = np.asarray(src_nose, np.float32)
    rm = np.asarray(ref_nose, bool)
    if rm.sum() < 8 or (w > 0).sum() < 8 or knee <= 0:
        return s.copy()
    rbox = _nonzero_box(rm)
    r = _pixels(_lab(np.asarray(ref, np.float32)[rbox]), rm[rbox])
    f = float(np.percentile(r[:, 0], percentile))
    box = _nonzero_box(w > 0)  # the weight's box only: the nose of a 1000 px face
    a = _lab(s[box])
    depth = np.maximum(f - a[..., 0], 0.0) * w[box]
    out = s.copy()
    if not (depth > 0).any():
        return out
    dark_ab = r[r[:, 0] <= f, 1:].mean(axis=0)
    lab = a.copy()
    lab[..., 0] = a[..., 0] + depth - knee * np.log1p(depth / knee)
    t = (1.0 - np.exp(-depth / knee))[..., None]
    lab[..., 1:] = a[..., 1:] + t * (dark_ab - a[..., 1:])
    out[box] = np.where((depth > 0)[..., None], _rgb(lab), s[box])
    return out
