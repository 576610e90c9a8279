"""The puppet's mouth interior (:mod:`facetex.puppet.composite`, "mouth interior"): the driver's own
teeth, tongue and cavity drawn inside the puppet's inner lips, and the texture's interior filled from
its lips as the driver's lips close."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import BadInputError
from ..geometry.masks import polygon_mask, smoothstep
from ._contours import EDGE_MAX_PX, _mouth_frame, _open_fade, sample_between
from ._pixels import _LUMA, _shape2
from .lighting import _lab, _linear, _rgb, linear_to_srgb

#: linear luminance (CIELAB L* 40) below which the driver's lips are brightened to it before the
#: lip key (:func:`mouth_interior`): GRID's lips measure L* 42-49 (no run of ``facetex bench
#: puppet`` changes); at 0.45 x the sRGB values, 21-24, and the key took the teeth for lips
KEY_LIP_LUMINANCE = ((40.0 + 16.0) / 116.0) ** 3

__all__ = ["mouth_interior", "interior_white_balance", "mouth_closure", "fill_mouth_interior", "lift_inner_lips",
           "lip_ring", "lip_weights", "open_lip_weights", "lip_regions"]


def mouth_interior(frame, driver_lips, puppet_lips, shape=None, *, inset: float = 1.3,
                   closed: float = 0.02, soft: float = 0.3,
                   lip_key: tuple[float, float] | None = (4.0, 12.0),
                   cavity: float | None = 25.0, grow: float = 0.015,
                   edge: float = 0.025, lip_shade: float | None = 0.3,
                   cavity_shading: bool = True,
                   soft_px: float | None = EDGE_MAX_PX) -> tuple[np.ndarray, np.ndarray]:
    """The driver's mouth interior moved into the puppet's mouth: (image (H, W, 3), alpha (H, W)).

    ``driver_lips``, ``puppet_lips`` (8, 2): iBUG inner-lip points 60-67 in ``frame`` px (driver)
    and output px (puppet). Both inner-lip contours are drawn as smooth curves
    (:func:`~facetex.puppet._contours.sample_between`), and every puppet pixel takes the driver's pixel at the same place between the corners (along
    the corner line) and between the upper and lower lip (across it): teeth, tongue and the dark
    cavity land where they are in the driver's mouth, whatever the two mouths' shapes. Both
    coordinates are scaled about the mouth's centre by ``inset`` (< 1: the edge samples the
    driver's interior, not its lips; > 1, across the opening only: the driver's whole interior
    lands inside the soft edge below and the edge samples the driver's lips, which the lip key
    removes). 1.3, the default: at 1 the driver's upper teeth, just under its lip, fell in the soft
    edge's ramp and showed as a faint grey band in a smaller-lipped persona's opening (Arroyo on GRID
    lrwp9a, at 100 %); at 1.3 a thin lighter strip. ``facetex bench puppet --stress`` (60 runs,
    256 px): mouth slopes 0.87-1.19 (mean 1.023) at 1, 0.90-1.20 (1.016) at 1.3, mouth r >= 0.919 /
    0.917, Arroyo/lrwp9a 0.90 -> 0.98 (1.3 along the corner line too, which samples the driver's
    skin beyond its corners: 0.89-1.19); a smaller inset shrank the teeth (earlier: Arroyo/lrwp9a
    0.77 at 0.9, 0.72 at 0.8). Where the soft edge is capped (``soft_px``: a 1000 px smile) the
    margin is the pixels it is where the cap starts (half of a ``soft_px`` / ``soft`` gap x (1 -
    1 / ``inset``): 1.5 px), and it moves only the ramp's pixels (``edge_margin`` of
    :func:`~facetex.puppet._contours.sample_between`): deeper, the driver's interior is drawn at its
    own size. Scaled about the centre (at 1.3 the driver's teeth, lip to lip, filled 0.77 of the
    puppet's opening under a dark band; with the scale cut with the ramp, 1.3 -> ~1.1 on a 40 px gap
    but ~1.27 on a 15 px one) the teeth were drawn up to 1/1.27 as tall and dlib read 1000 px smiles
    0.85-0.95 as open as the drivers' (Williams on FRL 006: 0.78).
    Alpha: 0 outside the puppet's inner lips, rising to 1 over ``soft`` x the opening's widest gap
    inside them (the puppet's lips overlap the interior: no polygon edge; 0.3, as the eyes'
    (:func:`~facetex.puppet.eyes.eye_interior`): at 0.15 dlib read the widest, teeth-showing
    frames of Koizumi's persona on GRID bbaf2n as a quarter open, and
    ``facetex bench puppet``'s worst mouth r was 0.843, 0.893 at 0.3; its slopes 0.886-1.208 at
    256 px, 0.891-1.223; at 360 px 0.844-1.147, 0.896-1.118), faded out as the driver's lip gap
    falls from 2 x ``closed`` to ``closed`` times its mouth width (closed lips have no interior to
    show). ``lip_key`` (lo, hi): the driver's own
    lips are keyed out of the interior (None: off): dlib's inner-lip points of a slightly open
    mouth sit on the lips, whose red, stretched over the puppet's opening, drew a flat red
    polygon. A pixel counts as lip unless its colour (CIELAB a, b) differs from the lips' or
    it is lighter (alpha x 0 when the larger of the two differences is <= lo, x 1 when >= hi):
    the inner lip surface has the lips' colour, only darker, while the cavity and tongue in
    shadow lose it and teeth lose it and gain light (measured on GRID clips with the Bush and
    Blair puppets: median a-b distance 3-4 on the inner lip surface of slightly open mouths,
    14-25 in open mouths with teeth).
    The lips' colour is the median of the driver's frame just above its upper inner-lip curve at the
    upper lip, just below the lower one at the lower lip, blended across the opening (one median for
    both kept a glossy lower lip, lighter than the upper, as a pink band under the teeth that dlib
    read as lip: mouth slope 0.51 on FRL 006 with Williams' persona, 0.72 now); lips
    darker than L* 40 are brought to it (one gain on the linear light of the lips and the
    interior, :data:`KEY_LIP_LUMINANCE`) before the differences are measured.
    ``cavity`` (percentile, None: off): under the interior's soft edge and its keyed-out lips, the
    puppet's whole opening, from ``grow`` x its mouth width outside its contour in, is the mean
    colour of the interior's darkest ``cavity`` % (the cavity's shadow; 0.35 x the driver's lip
    colour when all of the interior is keyed out) instead of the persona's texture, while both
    mouths are open (the same fade at ``closed``). Measured with ``facetex bench puppet`` (6
    personas x 6 GRID clips): with the puppet's lips in the lips' colour
    (:func:`lip_regions`) the persona's own teeth at its texture's inner
    lips had been what made an opening read open: without them (the texture's interior filled,
    :meth:`~facetex.puppet.Puppeteer.textures`) and without the cavity Arroyo's mouth-opening
    slopes fell to 0.58-0.82; with the cavity at the contour (``grow`` 0) to 0.72-0.90 (its
    slightly open mouths a thin line); with ``closed`` 0.04 -> 0.02 and ``grow`` 0.015 all 36 runs
    read 0.87-1.25 (before: 0.82-1.29 with white rims), mouth r >= 0.90 (0.87). Without the soft
    edge (the interior's alpha 1 from the grown contour) the opening's edge turned light on
    Williams' and Koizumi's lower lips and Arroyo/lbax4n read 0.80. The cavity's edge ramps over
    ``edge`` x the mouth width (at least a pixel): at 256 px a pixel, as measured above; at 512 px
    the upscaled driver's frame is soft and a 1 px edge drew the slit of a slightly open mouth as a
    cut-out. ``lip_shade`` (with ``lip_key``; None: off): at the puppet's contour the cavity's colour is
    the driver's lip colour times this (linear light: the inner lip surface in the mouth's shade),
    turning into the cavity's shadow over the soft edge's ramp. With the darkest interior's colour up
    to the contour every open mouth had a uniform dark brown ring round the teeth (a drawn outline
    at 100 %; the driver shows its lips' red inner surface there). Measured with ``facetex bench
    puppet`` (36 GRID runs): the lighter the ring, the less open dlib reads the mouth. At 360 px mouth
    slopes 0.887-1.112 (mean 0.986), r >= 0.929 at 0.3; 0.833-1.083 (0.953), 0.919 at 0.45; 0.898-1.119
    (0.987), 0.937 with the dark ring; at 0.45 with the lips' tone over the ramp's first half only,
    0.815-1.086. At 256 px and 0.45: 0.889-1.237, r 0.907 (0.933-1.229, 0.920 with the ring; 0.841-1.229,
    0.894 at 0.6 with a first version of the lift's taper). ``cavity_shading`` (with ``lip_key``):
    where the key took the interior out as lip, the cavity is the driver's interior itself, scaled
    (linear light, per channel) so that its mean over the opening is the cavity's colour, instead of
    that colour flat: a tongue or inner lip keyed out as lip is a tongue in shadow, not a flat brown
    slot with straight edges (wide-open mouths at 360 px); elsewhere under the soft edge the flat
    colour stays (teeth there had drawn a light rim that dlib read as part of the opening).
    ``soft_px`` (None: off): the ramp is at most this many pixels wide, never under
    :data:`~facetex.puppet._contours.EDGE_MIN_SOFT` x the widest gap
    (:meth:`~facetex.puppet._contours.Between.edge`): the ramp and the lip shade over it are the
    shadow just inside the lips, a pixel or three on a GRID face, but 0.3 of a 1000 px driver's
    smile (a 50 px gap) drew a 15 px dark maroon band between the driver's teeth and the puppet's
    lower lip (FRL 002, every persona). Up to a 13 px gap (every mouth of a 256 px frame) nothing
    changes."""
    f = np.asarray(frame, np.float32)
    h, w = _shape2(f.shape if shape is None else shape)
    dp = np.asarray(driver_lips, np.float64)
    pp = np.asarray(puppet_lips, np.float64)
    if dp.shape != (8, 2) or pp.shape != (8, 2):
        raise BadInputError(f"inner lips must be (8, 2) points 60-67, got {dp.shape} and {pp.shape}")
    none = np.zeros((h, w, 3), np.float32), np.zeros((h, w), np.float32)
    if not (np.isfinite(dp).all() and np.isfinite(pp).all()):
        return none
    _, _, wd, gd = _mouth_frame(dp)
    _, _, wp, gp = _mouth_frame(pp)
    # closed driver lips have no interior to show (their sliver would draw a red line): fade out
    fade = _open_fade(wd, gd, closed)
    # the cavity's shadow: where both mouths are open
    dark_fade = fade * _open_fade(wp, gp, closed) if cavity is not None else 0.0
    if max(fade, dark_fade) <= 0:
        return none
    s = sample_between(f, dp, pp, (h, w), inset=inset)
    if s is None:
        return none
    if inset > 1 and soft_px is not None:
        # where the ramp is capped (a 1000 px smile) the inset's margin stays the px it is where the
        # cap starts, and only the ramp's pixels are moved by it: scaled about the centre, the
        # driver's teeth had been drawn 1/inset as tall (dlib read the puppets' smiles 0.85-0.95 as
        # open as the drivers' on the 1000 px portrait runs, Williams' 0.78)
        r = s.ramp_width(soft, max_px=soft_px)
        uncapped = soft * float(s.gap.max())
        if r < uncapped:
            margin = 0.5 * r / soft * (1.0 - 1.0 / inset)  # the landing depth of a gap whose ramp is r
            s = sample_between(f, dp, pp, (h, w), edge_margin=(margin, r)) or s
    x0, y0, x1, y1 = s.box
    gap, depth, warped = s.gap, s.depth, s.warped
    up_d, lo_d, du0, du1, Rd, cd, _ = s.driver
    # one ramp width for the whole mouth (its widest gap's): the thin parts towards the corners
    # fade instead of ending in hard tips
    alpha = np.zeros((h, w), np.float32)
    ramp = s.edge(soft, max_px=soft_px)
    alpha[y0:y1, x0:x1] = ramp * fade
    if alpha.max() <= 0 and dark_fade <= 0:
        return none
    lin = _linear(warped)
    lab = cv2.cvtColor(lin, cv2.COLOR_LRGB2Lab)  # _lab(warped), its linear light kept for the key
    keyed = None  # how far the key took each pixel out as lip
    if lip_key is not None:
        # the driver's lips: just above its upper and below its lower inner-lip curve, middle 60 %
        us = du0 + np.linspace(0.2, 0.8, 9) * (du1 - du0)
        off = 0.04 * wd + 1.0
        ring = np.concatenate([np.stack([us, up_d(us) - off], -1), np.stack([us, lo_d(us) + off], -1)]) @ Rd + cd
        lip = cv2.remap(f, ring[None, :, 0].astype(np.float32), ring[None, :, 1].astype(np.float32), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
        lip_lin = _linear(lip)
        # a dim frame's teeth differ from its lips by a few CIELAB units only: keyed at the
        # exposure that brings the lips to KEY_LIP_LUMINANCE
        gain = max(1.0, KEY_LIP_LUMINANCE / max(float(np.median(lip_lin[0] @ _LUMA)), 1e-4))
        key_lab = lab if gain == 1.0 else cv2.cvtColor(np.minimum(lin * gain, 1.0), cv2.COLOR_LRGB2Lab)
        ring_lab = cv2.cvtColor(np.minimum(lip_lin * gain, 1.0), cv2.COLOR_LRGB2Lab)[0]
        # each lip its own colour, blended across the opening: a glossy lower lip much lighter than
        # the upper lip was "lighter than the lips" and stayed in the opening as a pink band
        up_lab, lo_lab = np.median(ring_lab[:len(us)], axis=0), np.median(ring_lab[len(us):], axis=0)
        lip_lab = up_lab + smoothstep(s.across)[..., None].astype(np.float32) * (lo_lab - up_lab)
        unlike = np.maximum(np.linalg.norm(key_lab[..., 1:] - lip_lab[..., 1:], axis=-1),
                            key_lab[..., 0] - lip_lab[..., 0])
        lo, hi = lip_key
        k = np.clip((unlike - lo) / max(hi - lo, 1e-6), 0.0, 1.0)
        k = smoothstep(k).astype(np.float32)
        # smoothed over the mouth opening only (normalized convolution): the box's pixels outside
        # the lips sample the driver's lips and would darken a thin opening's key
        inside = (alpha[y0:y1, x0:x1] > 0).astype(np.float32)
        k = cv2.GaussianBlur(k * inside, (0, 0), 1.0) / np.maximum(cv2.GaussianBlur(inside, (0, 0), 1.0), 1e-6)
        alpha[y0:y1, x0:x1] *= np.clip(k, 0.0, 1.0)
        keyed = 1.0 - np.clip(k, 0.0, 1.0)
    if cavity is None:
        img = np.zeros((h, w, 3), np.float32)
        img[y0:y1, x0:x1] = warped
        return img, alpha
    # under the interior: the cavity's shadow from just outside the puppet's contour in, not the
    # persona's texture there. A persona whose photos smile has teeth up to its
    # texture's inner lips: the interior's soft edge and the keyed-out lips let them through
    # as a white rim that dlib read as part of the opening (Williams' persona on GRID lbax4n).
    base = np.zeros((h, w), np.float32)
    base[y0:y1, x0:x1] = smoothstep(np.clip((depth + 0.5 + grow * wp) / max(1.0, edge * wp), 0.0, 1.0)) \
        * np.clip(gap, 0.0, 1.0) * dark_fade
    inner = alpha[y0:y1, x0:x1] > 0.5
    lum = lab[..., 0]
    dark = warped[inner & (lum <= np.percentile(lum[inner], cavity))] if inner.sum() >= 8 else None
    colour = dark.mean(axis=0) if dark is not None and len(dark) else 0.35 * lip.mean(axis=(0, 1)) \
        if lip_key is not None else np.zeros(3, np.float32)
    opening = ramp > 0
    if cavity_shading and keyed is not None and dark is not None and len(dark) and opening.sum() >= 8:
        # where the key took the interior out as lip, its own shading at the cavity's darkness (elsewhere
        # under the soft edge the flat colour: teeth there had drawn a light rim read as the opening)
        scale = _linear(np.asarray(colour, np.float32)) / np.maximum(lin[opening].mean(axis=0), 1e-4)
        flat = np.broadcast_to(np.asarray(colour, np.float32), lin.shape)
        colour = flat + keyed[..., None] * (linear_to_srgb(lin * scale.astype(np.float32)) - flat)
    if lip_shade is not None and lip_key is not None:
        # the lips' shaded inner surface at the contour, the cavity's shadow from the ramp's end in
        shade = linear_to_srgb(np.median(lip_lin[0], axis=0) * np.float32(lip_shade))
        colour = shade + ramp[..., None] * (np.asarray(colour, np.float32) - shade)
    total = alpha + (1.0 - alpha) * base
    # alpha and base are 0 outside the box: the mix is computed in it only
    a, tb = alpha[y0:y1, x0:x1, None], total[y0:y1, x0:x1, None]
    mix = np.zeros((h, w, 3), np.float32)
    mix[y0:y1, x0:x1] = np.where(tb > 0, (a * warped + (1.0 - a) * base[y0:y1, x0:x1, None] * colour)
                                 / np.maximum(tb, 1e-6), 0.0)
    return mix, total.astype(np.float32)


def _inner_lip_band(points68, box, width: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(band, inside, body, distance) of ``box`` (x0, y0, x1, y1): bool (h, w) the lips (outer
    contour 48-59) within ``width`` px outside the inner-lip contour 60-67 (band), the inside of that
    contour, and the rest of the lips; float32 (h, w) each pixel's distance (px) outside that contour
    (0 inside)."""
    x0, y0, x1, y1 = box
    p = np.asarray(points68, np.float64) - [x0, y0]
    shape = (y1 - y0, x1 - x0)
    inner = polygon_mask(p[60:68], shape) > 0.5
    d = cv2.distanceTransform((~inner).astype(np.uint8), cv2.DIST_L2, 3)
    lips = (d > 0) & (polygon_mask(p[48:60], shape) > 0.5)
    return lips & (d <= width), inner, lips & (d > width), d


def lift_inner_lips(image, frame, driver68, puppet68, *, band: float = 0.1, closed: float = 0.02,
                    quantiles: tuple[float, float] = (10.0, 50.0), top: float = 90.0,
                    chroma_lift: float = 20.0, relative: bool = False) -> np.ndarray:
    """``image`` (H, W, 3) sRGB float, the puppet, with the lightness of its open lips' inner band
    raised to the driver's: the lips within ``band`` x the mouth width outside each face's inner-lip
    contour (iBUG 60-67; ``driver68`` in ``frame``, ``puppet68`` in ``image``, the same size).
    The puppet's band lightness (CIELAB L*) at its ``quantiles`` is lifted by how much darker it is
    there than the driver's band at the same quantiles (linear between them, the lowest one's lift
    below it, falling to none at the puppet's ``top`` percentile; never darkened, never lifted past
    the driver's band at its highest quantile: a one-way histogram match of the band's darker part;
    the driver's band can hold its teeth, and a lighter top drew a light rim; in full up to half the
    band's width from the contour, tapering to none on the lips at 1.5 widths), faded in with both
    mouths' opening (as :func:`mouth_interior`'s cavity). The opening's first 1.5 px inside the
    puppet's contour, under the interior's soft edge, are lifted the same way. A pixel lifted by
    ``chroma_lift`` L* or more takes the driver's band chroma (CIELAB a*, b* median), less lifted
    ones in part. ``relative``: the driver's band is taken relative to its own lips (the lips
    beyond the band: their median L*, a*, b* moved to the puppet's), for a puppet that keeps its own
    lip colour (composite ``colour="persona"`` or no lighting), which the driver's band would light
    up as a rim. Why: a thin-lipped persona's texture holds the dark gap of its mostly closed photos
    at its inner lips; stretched over an open mouth it drew a near-black ring round the driver's
    teeth (Bush on GRID id2: band L* 10th percentile 7 against the driver's 31) that dlib read as
    part of the opening.
    Written by hand: no library matches histograms one way on a landmark band."""
    img = np.asarray(image, np.float32)
    dp, pp = np.asarray(driver68, np.float64), np.asarray(puppet68, np.float64)
    if dp.shape != (68, 2) or pp.shape != (68, 2) or not (np.isfinite(dp).all() and np.isfinite(pp).all()):
        return img
    _, _, wd, gd = _mouth_frame(dp[60:68])
    _, _, wp, gp = _mouth_frame(pp[60:68])
    fade = _open_fade(wd, gd, closed) * _open_fade(wp, gp, closed)
    if fade <= 0:
        return img
    h, w = _shape2(img.shape)

    def box(p):
        m = max(2, int(np.ceil(band * max(wd, wp))) + 2)
        lo, hi = np.floor(p[48:60].min(axis=0)).astype(int) - m, np.ceil(p[48:60].max(axis=0)).astype(int) + m
        return max(0, lo[0]), max(0, lo[1]), min(w, hi[0]), min(h, hi[1])

    bp, bd = box(pp), box(dp)
    if bp[2] - bp[0] < 3 or bp[3] - bp[1] < 3 or bd[2] - bd[0] < 3 or bd[3] - bd[1] < 3:
        return img
    (mp, inner, bodyp, out_d), (md, _, bodyd, _) = (_inner_lip_band(pp, bp, max(1.0, band * wp)),
                                                    _inner_lip_band(dp, bd, max(1.0, band * wd)))
    if mp.sum() < 8 or md.sum() < 8:
        return img
    lab = _lab(img[bp[1]:bp[3], bp[0]:bp[2]])
    lab_d = _lab(np.asarray(frame, np.float32)[bd[1]:bd[3], bd[0]:bd[2]])
    ld = lab_d[md]
    # relative: the driver's band as far from its lips as it is, put on the puppet's lips. Not by
    # default: with the driver's lip colour the lips' medians differ by their region only (measured
    # with bench puppet: Chavez's slopes +0.03-0.07, the worst mouth r 0.900 -> 0.885)
    offset = np.median(lab[bodyp], axis=0) - np.median(lab_d[bodyd], axis=0) \
        if relative and bodyp.sum() >= 8 and bodyd.sum() >= 8 else np.zeros(3, np.float32)
    # tied quantiles (a band of two flat colours) made strictly increasing for the interpolation
    qp = np.percentile(lab[..., 0][mp], [*quantiles, top]) + 1e-3 * np.arange(len(quantiles) + 1)
    qd = np.percentile(ld[:, 0], quantiles) + offset[0]
    lift = np.r_[np.maximum(qd - qp[:-1], 0.0), 0.0]
    if lift.max() <= 0:
        return img
    # in full to half the band's width, tapering to none at 1.5 widths on the lips: a band lifted in
    # full to its edge drew a light, jagged line along it where the texture's dark gap is wider
    # than the band (Bush on GRID bbaf2n). Also lifted: the opening's first 1.5 px inside the
    # contour, which the interior's soft edge and the cavity only partly cover: left dark, the
    # pixels the contour cuts drew a beaded line along it
    rim = inner & (cv2.distanceTransform(inner.astype(np.uint8), cv2.DIST_L2, 3) <= 1.5)
    taper = np.where(inner, 1.0, np.clip(1.5 - out_d / max(1.0, band * wp), 0.0, 1.0) * (mp | bodyp)).astype(np.float32)
    wgt = np.maximum(cv2.GaussianBlur(taper, (0, 0), 0.7) * ~inner, rim) * fade  # (1 inside: no pull at the contour)
    L = lab[..., 0]
    dl = wgt * np.clip(np.minimum(np.interp(L, qp, lift), qd[-1] - L), 0.0, None)
    lab[..., 0] += dl
    # a lifted near-black keeps next to no colour (grey lips): it takes the driver's band
    # chroma as far as it was lifted (fully from a lift of ``chroma_lift`` L*)
    t = np.clip(dl / chroma_lift, 0.0, 1.0)[..., None]
    lab[..., 1:] += t * (np.median(ld[:, 1:], axis=0) + offset[1:] - lab[..., 1:])
    out = img.copy()
    sub = out[bp[1]:bp[3], bp[0]:bp[2]]
    moved = dl > 0  # the Lab round trip elsewhere would move pixels by float error
    sub[moved] = _rgb(lab)[moved]
    return out


def mouth_closure(inner_lips, closed: float = 0.04) -> float:
    """How closed a mouth is, from its inner-lip points 60-67 (8, 2): 1 when the lip gap is at most
    ``closed`` x the mouth width, 0 from twice that (smooth in between): the complement of
    :func:`mouth_interior`'s fade."""
    p = np.asarray(inner_lips, np.float64)
    if p.shape != (8, 2) or not np.isfinite(p).all():
        return 0.0
    _, _, wd, gd = _mouth_frame(p)
    return 1.0 - _open_fade(wd, gd, closed)


def _vertical_ramps(filled: np.ndarray, hole: np.ndarray) -> np.ndarray:
    """``filled`` with each column of ``hole`` replaced by the straight ramp between that column's
    top and bottom hole pixels. Inpainted from both lips, the hole is dark above a hard seam and
    pink below; squeezed to a line by the closing mesh and sampled at sub-pixel heights that drift
    along the mouth, the seam came out as stair steps of dark and pink runs. A ramp has about the
    same mean but no seam, so the line's colour drifts smoothly instead."""
    out = filled.copy()
    cols = np.flatnonzero(hole.any(axis=0))
    if cols.size == 0:
        return out
    hc = hole[:, cols]
    top = hc.argmax(axis=0)
    bottom = hole.shape[0] - 1 - hc[::-1].argmax(axis=0)
    y = np.arange(hole.shape[0])[:, None]
    f = np.clip((y - top) / np.maximum(bottom - top, 1), 0.0, 1.0)[..., None]
    ramp = filled[top, cols][None] + f * (filled[bottom, cols] - filled[top, cols])[None]
    sub = out[:, cols]
    sub[hc] = ramp[hc]
    out[:, cols] = sub
    return out


def fill_mouth_interior(texture, inner_lips, closure: float) -> np.ndarray:
    """``texture`` (H, W, 3) float with the inside of its inner-lip contour ``inner_lips`` (8, 2),
    grown by a pixel, filled from the lips around it (OpenCV's Telea inpainting, then each column a
    straight ramp between its ends: :func:`_vertical_ramps`), mixed in by ``closure`` in [0, 1]
    (:func:`mouth_closure` of the frame's mouth). A persona whose photos mostly smile has teeth
    between its average's inner lips; lips that close over them leave a sub-pixel sliver that
    rendered as a white strip between dark lines (read as an open mouth)."""
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
    filled = _vertical_ramps(cv2.inpaint(u8, hole, 2, cv2.INPAINT_TELEA).astype(np.float32) / 255, hole > 0)
    a = c * cv2.GaussianBlur(hole.astype(np.float32), (0, 0), 0.7)[..., None]
    out = t.copy()
    out[y0:y1, x0:x1] = roi + a * (filled - roi)
    return out


def _lip_median(image: np.ndarray, points68: np.ndarray) -> np.ndarray | None:
    """Median linear-light RGB (3,) of the lips (outer contour 48-59 minus the inner 60-67) of
    ``image`` at ``points68``, or None when they cover fewer than 8 pixels."""
    h, w = _shape2(image.shape)
    x0, y0 = (max(0, int(np.floor(v)) - 1) for v in points68[48:60].min(axis=0))
    x1, y1 = (min(n, int(np.ceil(v)) + 2) for n, v in zip((w, h), points68[48:60].max(axis=0)))
    if x1 - x0 < 3 or y1 - y0 < 3:
        return None
    _, _, lips, _ = _inner_lip_band(points68, (x0, y0, x1, y1), 0.0)  # no band: all of the lips
    if lips.sum() < 8:
        return None
    return np.median(_linear(image[y0:y1, x0:x1][lips]), axis=0)


def interior_white_balance(interior, frame, driver68, image, puppet68, *, bounds=(0.5, 2.0)) -> np.ndarray:
    """``interior`` (H, W, 3) sRGB, the driver's mouth interior (:func:`mouth_interior`), in the
    puppet's white balance: per channel in linear light, times the square root of the ratio of the
    puppet's lips (``image`` at ``puppet68``) to the driver's (``frame`` at ``driver68``), its
    luminance divided out (the colour cast only: the teeth keep their lightness) and bounded. For a
    puppet in the persona's own colour (face mode): GRID lbax4n's orange light made the driver's
    teeth and tongue an orange blob in a persona-coloured face; the full ratio turned them olive
    (part of it is the two people's lips)."""
    f = np.asarray(interior, np.float32)
    d = _lip_median(np.asarray(frame, np.float32), np.asarray(driver68, np.float64))
    p = _lip_median(np.asarray(image, np.float32), np.asarray(puppet68, np.float64))
    if d is None or p is None:
        return f
    g = np.sqrt(p / np.maximum(d, 1e-4))  # half the lips' cast: the rest is the two people's lips
    g = np.clip(g / max(float(g @ _LUMA), 1e-6), *bounds).astype(np.float32)
    return linear_to_srgb(_linear(f) * g).astype(np.float32)


def lip_ring(points68, shape, *, outer=None) -> np.ndarray:
    """bool (H, W): the lip pixels at iBUG landmarks ``points68`` (outer polygon 48-59 minus inner
    60-67, a pixel in from both edges), where lip colour and detail are measured; ``outer``: the
    outer polygon's mask if the caller has it."""
    p = np.asarray(points68, np.float64)
    h, w = _shape2(shape)
    outer = polygon_mask(p[48:60], (h, w)) if outer is None else outer
    ring = ((outer > 0.5) & ~(polygon_mask(p[60:68], (h, w)) > 0.5)).astype(np.uint8)
    return cv2.erode(ring, np.ones((3, 3), np.uint8)) > 0


def lip_weights(points68, shape, *, feather: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """(weight (H, W) float32, bool (H, W)) of the lips at iBUG landmarks ``points68``: the outer
    lip polygon 48-59 feathered by ``feather`` x the eye-corner distance (Gaussian sigma), and the
    lip pixels themselves (outer polygon minus inner 60-67, a pixel in from both edges) where
    their colour is measured (:func:`~facetex.puppet.lighting.transfer_skin_colour`)."""
    p = np.asarray(points68, np.float64)
    h, w = _shape2(shape)
    outer = polygon_mask(p[48:60], (h, w))
    sig = max(0.75, feather * float(np.linalg.norm(p[36] - p[45])))
    return np.clip(cv2.GaussianBlur(outer.astype(np.float32), (0, 0), sig), 0, 1), lip_ring(p, (h, w), outer=outer)


def open_lip_weights(points68, shape, *, feather: float = 0.02, band: float = 0.1,
                     corner: float = 0.15) -> list:
    """The upper and the lower lip as two regions of
    :func:`~facetex.puppet.lighting.transfer_skin_colour`: [(weight (H, W), pixels (H, W) bool)] x 2,
    each weight scaled by how open the mouth is (1 - :func:`~facetex.puppet.mouth.mouth_closure`;
    [] for closed lips). One median colour for both lips let an open mouth's dark inner-lip
    seam and the driver's teeth pull the lips' colour apart from the driver's, and dlib then
    read part of the upper lip as the opening (Arroyo's persona on GRID lbax4n: mouth-opening
    slope 0.71; 0.83 with each lip its own colour). Fading with openness keeps closed lips one
    colour: an earlier per-lip split without the fade broke Chavez's closed lips. The colour is
    measured on each lip's outer part: the inner-lip points pulled ``band`` of the way towards
    the outer lip contour (0.1: Arroyo/bbaf2n's mouth r 0.83 -> 0.86 over the whole lip, 0.88 at 0.2
    and 0.4, but Bush/sbwe5n's slope 1.10 -> 1.19, 1.32 at 0.2, 1.37 at 0.4, Arroyo/lbax4n
    0.83, 0.80, 0.75: the inner band carries some of the driver's look of the opening). The
    weights fall to 0 over ``corner`` x the mouth width at each corner."""
    p = np.asarray(points68, np.float64)
    h, w = _shape2(shape)
    o = 1.0 - mouth_closure(p[60:68])
    if o <= 0:
        return []
    sig = max(0.75, feather * float(np.linalg.norm(p[36] - p[45])))
    # the colour is measured on each lip's outer part only: the inner-lip points of the driver
    # (dlib) and the puppet's (mesh) opening differ, and the inner band of either image can hold
    # the dark interior, which darkened the upper lip of Arroyo's persona on GRID bbaf2n
    q = p.copy()
    for inner, outer in ((61, 50), (62, 51), (63, 52), (65, 56), (66, 57), (67, 58)):
        q[inner] = p[inner] + band * (p[outer] - p[inner])
    # tapered to 0 at the mouth corners, where the two lips' thin wedges meet the corner's
    # shadow: each lip's own colour offset there drew dark red ticks (Arroyo/bbaf2n, 8x crops);
    # the lips' common colour (lip_weights) stays
    axis = p[54] - p[48]
    t = (((np.arange(w) - p[48, 0]) * axis[0])[None, :] + ((np.arange(h) - p[48, 1]) * axis[1])[:, None]) \
        / max(float(axis @ axis), 1e-9)
    taper = np.clip(np.minimum(t, 1.0 - t) / corner, 0.0, 1.0).astype(np.float32) if corner > 0 else 1.0
    parts = []
    for upper in (True, False):
        idx = [*range(48, 55), 64, 63, 62, 61, 60] if upper else [*range(54, 60), 48, 60, 67, 66, 65, 64]
        m = polygon_mask(p[idx], (h, w))
        ring = cv2.erode((polygon_mask(q[idx], (h, w)) > 0.5).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        parts.append((o * taper * np.clip(cv2.GaussianBlur(m.astype(np.float32), (0, 0), sig), 0, 1), ring))
    return parts


def lip_regions(driver68, puppet68, shape, *, open_lips: bool = True) -> dict:
    """``lips`` and ``lip_parts`` of :func:`~facetex.puppet.lighting.transfer_skin_colour` for a
    puppet with landmarks ``puppet68`` in a frame with the driver's ``driver68`` (both (68, 2) px
    of an image of ``shape``): the lips' colour where the *puppet's* lips are (:func:`lip_weights`,
    :func:`open_lip_weights` with ``open_lips``), measured on each face's own lip pixels
    (``puppet68`` None: the driver's lips for both). Placed at the driver's lips, a fuller-lipped
    persona's lip edge outside them took the skin's mapping and its lighter lips turned white
    (Serena Williams' persona on GRID lbax4n: a white rim round the opening)."""
    dw = lip_weights(driver68, shape)
    dparts = open_lip_weights(driver68, shape) if open_lips else []
    if puppet68 is None:
        return {"lips": dw, "lip_parts": dparts}
    pw = lip_weights(puppet68, shape)
    pparts = open_lip_weights(puppet68, shape) if open_lips else []
    parts = [(p[0], d[1], p[1]) for d, p in zip(dparts, pparts)] if dparts and pparts else []
    return {"lips": (pw[0], dw[1], pw[1]), "lip_parts": parts}
