"""Skin masks: the face region minus eyes, brows, lips and nostrils, minus hair, glasses
and other occluders. One module for both papers (FaceTex: where texture may change and
where style patches may come from; Persona: what belongs to the face).

Three parts, combined by :func:`~facetex.geometry.segment.skin_mask`:

1. the **face region**: the jaw + extrapolated forehead arc of
   :func:`.masks.face_outline`, below the brows replaced by MediaPipe's face oval
   (468-point mesh) when given, which follows the cheeks and jaw more closely;
2. the **features** (:func:`feature_mask`): eyes, brows, lips and nostrils from the 68
   landmarks, each grown by a margin relative to the face width (lids, lashes, lip line
   and brow hairs lie outside the landmark polygons);
3. the face's own **skin colour** (:func:`skin_colour_distance`): a Gaussian in CIELAB
   fitted robustly to the cheeks and the nose bridge (never the forehead, where a fringe
   may hang); pixels far from it in chroma, or much darker than the skin, are hair,
   brows, glasses frames, shadows of occluders or background. Lightness gets a wide
   tolerance because shading varies over a face more than skin chroma does;
4. **beards and stubble** (:func:`beard_mask`): darker and rougher than the skin on the
   lower face. They are hair: texture is not transferred onto or from them.

Choices made by looking at the masks of all 60 FRL London neutral portraits
(``benchmarks/skin_masks.py`` writes the overlay sheets): the face oval alone kept fringes
and hair strands inside the mask; a colour model fitted to the cheeks only rejected half
of many foreheads (its spread is too small), so it is fitted to the whole face region,
robustly; specular highlights (low chroma) are re-admitted as bright holes; the grown
brows can cut the forehead off from the cheeks, so large pieces are kept too; beards
pass the colour test and are caught by :func:`beard_mask`.
Hand-written (no library segments skin from a colour model seeded by landmarks).

Since issue 22 :func:`~facetex.geometry.segment.skin_mask` is the skin of
:func:`~facetex.geometry.segment.segment_face` (:mod:`facetex.geometry.segment`), which labels skin,
hair, brows, beard/stubble and specular highlights: the search region reaches past the
hairline, over the temples and to the jaw edge (:func:`head_region_mask`; the old region
stopped mid-forehead, so FaceTex changed only 36-57 % of the face and left a two-tone
forehead); skin-coloured (blond) strands are found by structure-tensor coherence
(:func:`hair_strand_mask`), stubble by dark-speck density (:func:`stubble_mask`),
highlights as bright low-saturation skin (:func:`highlight_mask`). ``skin_mask(...,
source=True)`` is what a style may lend texture from: no hair, beard, stubble-speckled
skin or highlights. Measured against hand-drawn outlines on 22 FRL portraits
(``benchmarks/skin_segmentation.py``): IoU skin 0.81 (the previous mask 0.70), hair 0.56,
beard 0.41. No package on the registry ships face-parsing weights usable here (checked:
mediapipe's wheel no longer carries .tflite models; HairSys ships a 35 MB MobileHairNet
checkpoint for top-of-head photos that needs torchvision and pinned torch 1.12; the
face-parsing / BiSeNet packages download their weights at run time).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import BadInputError
from ..io import LUMA_BT601
from .masks import disc, face_outline, face_width

__all__ = [
    "FACE_OVAL_468",
    "SkinParams",
    "feature_mask",
    "brow_mask",
    "face_region_mask",
    "skin_colour_distance",
    "beard_mask",
    "protected_mask",
]

#: MediaPipe face-mesh indices of the face oval, clockwise from the forehead top (10).
FACE_OVAL_468 = (10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377,
                 152, 148, 176, 149, 150, 136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109)

_EYES = (tuple(range(36, 42)), tuple(range(42, 48)))
_BROWS = (tuple(range(17, 22)), tuple(range(22, 27)))
_LIPS = tuple(range(48, 60))
_NOSTRILS = (31, 32, 33, 34, 35)


@dataclass(frozen=True)
class SkinParams:
    """Margins are fractions of the face width |p16 − p0| (≈ 330 px on a 1000 px FRL portrait)."""

    eye_margin: float = 0.045  # lids and lashes around the 6-point eye polygon
    brow_width: float = 0.075  # brow drawn as a line through its 5 points
    brow_margin: float = 0.02
    lip_margin: float = 0.02
    nostril_margin: float = 0.02
    chroma_sigmas: float = 4.0  # Mahalanobis radius in rg chromaticity
    dark_sigmas: float = 4.0  # darker than median − this × MAD(log I): hair, brows, frames
    highlight_sigmas: float = 2.0  # brighter than median + this × MAD(log I): a highlight, skin
    hole_fill: float = 0.04  # holes smaller than this (× face width)² are skin (highlights)
    feather: float = 0.012  # edge softness (Gaussian sigma) × face width
    min_piece: float = 0.02  # pieces not touching the cheeks are kept above this area × face width²
    occluder_min: float = 0.03  # off-colour pieces larger than (this × face width)² are occluders
    occluder_margin: float = 0.02  # occluders grown by this × face width (strand tips, hair edges)
    beard: bool = True  # beards and stubble are hair, not skin (see beard_mask)
    beard_texture: float = 2.0
    beard_dark: float = -0.5
    oval_shrink: float = 0.01  # pull the face oval in: its top point sits on the hairline
    # the whole skin (segment_face): the head region reaches past the hairline and the jaw edge
    head_ratio: float = 1.6  # forehead arc height × brow-to-nose-base above the brows
    jaw_grow: float = 0.015  # jaw line pushed out (× face width) to reach the jaw edge
    strand_energy: float = 4.0  # hair strands: structure-tensor energy × the bare skin's median
    strand_coherence: float = 0.45  # and coherence (one orientation)
    strand_edge: float = 0.5  # and edge consistency below this (lines, not a step edge)
    stubble_density: float = 0.06  # stubble: dark-speck density at least this
    stubble_ratio: float = 3.0  # and this × its density on the bare skin
    background_chroma: float = 0.4  # off-colour pieces less saturated than this × the skin: background
    highlight_chroma: float = 0.75  # highlights: saturation below this × the skin's
    source_margin: float = 0.02  # texture sources keep this × face width from hair and beard
    source_speck: float = 2.0  # and skip skin with over this × the bare skin's dark-speck density
    # and never the beard zone (upper lip and chin): short, grey or dark-on-dark stubble
    # passes the colour and speck tests there (FRL 043, 021, 067 carried 0.17-0.32 of their
    # lip/chin specks onto clean-shaven faces), so the style's skin there comes from elsewhere
    source_beard_zone: bool = True
    beard_zone_margin: float = 0.02  # the zone grown by this × face width


def _p68(points68) -> np.ndarray:
    p = np.asarray(points68, np.float64)
    if p.shape != (68, 2) or not np.all(np.isfinite(p)):
        raise BadInputError(f"expected finite (68, 2) landmarks, got shape {p.shape}")
    return p


def _shape(shape) -> tuple[int, int]:
    h, w = int(shape[0]), int(shape[1])
    if h < 1 or w < 1:
        raise BadInputError(f"mask shape must be positive, got {tuple(shape)[:2]}")
    return h, w


def _poly(canvas: np.ndarray, pts: np.ndarray, closed: bool = True, thickness: int = -1) -> None:
    q = np.round(np.asarray(pts) * 16).astype(np.int32)
    if thickness < 0:
        cv2.fillPoly(canvas, [q], 1, cv2.LINE_8, 4)
    else:
        cv2.polylines(canvas, [q], closed, 1, max(1, thickness), cv2.LINE_8, 4)


def _dilate(mask: np.ndarray, radius: float) -> np.ndarray:
    r = int(round(radius))
    if r < 1:
        return mask
    k = disc(r)
    return cv2.dilate(mask, k)


def protected_mask(points68, shape) -> np.ndarray:
    """bool (H, W): the meso-structures themselves — eye polygons, brows (a line through
    their points, 0.06 × face width wide) and the outer lip polygon, without margins. The
    region in which FaceTex must not change anything (``protected_change`` is measured here)."""
    p, (h, w) = _p68(points68), _shape(shape)
    fw = face_width(p)
    m = np.zeros((h, w), np.uint8)
    for eye in _EYES:
        _poly(m, p[list(eye)])
    for brow in _BROWS:
        _poly(m, p[list(brow)], closed=False, thickness=int(round(0.06 * fw)))
    _poly(m, p[list(_LIPS)])
    return m.astype(bool)


def brow_mask(points68, shape, params: SkinParams = SkinParams()) -> np.ndarray:
    """bool (H, W): both brows, each a line through its five points (17-21, 22-26)
    ``params.brow_width`` x the face width wide, grown by ``params.brow_margin`` x it."""
    p, (h, w) = _p68(points68), _shape(shape)
    fw = face_width(p)
    out = np.zeros((h, w), np.uint8)
    for brow in _BROWS:
        _poly(out, p[list(brow)], closed=False, thickness=int(round(params.brow_width * fw)))
    return _dilate(out, params.brow_margin * fw).astype(bool)


def feature_mask(points68, shape, params: SkinParams = SkinParams()) -> np.ndarray:
    """bool (H, W): eyes, brows, lips and nostrils grown by their margins (never skin)."""
    p, (h, w) = _p68(points68), _shape(shape)
    fw = face_width(p)
    out = np.zeros((h, w), np.uint8)
    for eye in _EYES:
        e = np.zeros_like(out)
        _poly(e, p[list(eye)])
        out |= _dilate(e, params.eye_margin * fw)
    out |= brow_mask(p, (h, w), params).view(np.uint8)
    lips = np.zeros_like(out)
    _poly(lips, p[list(_LIPS)])
    out |= _dilate(lips, params.lip_margin * fw)
    # nostrils: the nose base (31–35) and a band above it up to the alae
    nose = np.zeros_like(out)
    base = p[list(_NOSTRILS)]
    up = (p[33] - p[30]) * 0.2
    _poly(nose, np.vstack([base, base[::-1] - up]))
    out |= _dilate(nose, params.nostril_margin * fw)
    return out.astype(bool)


def face_region_mask(points68, shape, *, mesh=None, shrink: float = SkinParams.oval_shrink) -> np.ndarray:
    """bool (H, W): inside the jaw + forehead-arc outline of the 68 points, united with the
    face oval of the 468-point ``mesh`` if given (the oval follows the jaw and cheeks more
    closely, the arc reaches higher on tall foreheads); pulled in by ``shrink`` × face width."""
    p, (h, w) = _p68(points68), _shape(shape)
    out = np.zeros((h, w), np.uint8)
    _poly(out, face_outline(p))
    if mesh is not None:
        oval = np.zeros_like(out)
        _poly(oval, np.asarray(mesh, np.float64)[list(FACE_OVAL_468), :2])
        # the oval bounds the sides and chin; above the brows either may reach higher
        above = np.zeros_like(out)
        top = int(np.clip(np.floor(p[17:27, 1].min()), 0, h))
        above[:top] = 1
        out = np.where(above > 0, out | oval, oval).astype(np.uint8)
    r = int(round(shrink * face_width(p)))
    if r >= 1:
        out = cv2.erode(out, disc(r))
    return out.astype(bool)


def _sample_regions(p: np.ndarray, shape) -> np.ndarray:
    """bool (H, W): cheek discs and the nose bridge — skin on nearly every face."""
    h, w = shape
    fw = face_width(p)
    m = np.zeros((h, w), np.uint8)
    r = max(2, int(round(0.07 * fw)))
    for idx in ((2, 31, 41, 48), (14, 35, 46, 54)):
        c = p[list(idx)].mean(0)
        cv2.circle(m, (int(round(c[0])), int(round(c[1]))), r, 1, -1)
    cv2.line(m, tuple(np.round(p[28]).astype(int)), tuple(np.round(p[30]).astype(int)), 1,
             max(1, int(round(0.05 * fw))))
    return m.astype(bool)


def _rgb01(image) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise BadInputError(f"expected an (H, W, 3) RGB image, got shape {img.shape}")
    return img.astype(np.float32) / (255.0 if img.dtype == np.uint8 else 1.0)


def _colour_features(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """rg chromaticity (H, W, 2) — nearly invariant to shading under a white light — and
    log intensity (H, W)."""
    s = rgb.sum(-1) + 1e-3
    chrom = rgb[..., :2] / s[..., None]
    return chrom.astype(np.float32), np.log(s / 3.0 + 1e-3).astype(np.float32)


def _quadratic_form(d: np.ndarray, m: np.ndarray) -> np.ndarray:
    """d^T m d over the last axis (2) of ``d`` with a symmetric 2 x 2 ``m`` (einsum's generic
    loop is several times slower on these small images)."""
    d0, d1 = d[..., 0], d[..., 1]
    return m[0, 0] * d0 * d0 + (m[0, 1] + m[1, 0]) * d0 * d1 + m[1, 1] * d1 * d1


def _inv2(m: np.ndarray) -> np.ndarray:
    """Inverse of a 2 x 2 matrix."""
    a, b, c, d = m[0, 0], m[0, 1], m[1, 0], m[1, 1]
    return np.array([[d, -b], [-c, a]]) / (a * d - b * c)


def skin_colour_distance(image, points68, *, region=None) -> tuple[np.ndarray, np.ndarray]:
    """(chromaticity distance, log-intensity z-score), float32 (H, W), of every pixel from
    the face's skin colour. The model is fitted robustly to ``region`` (bool, default the
    cheeks and nose bridge): median start, then three rounds of a trimmed Gaussian on the
    rg chromaticity (covariance floored at 0.006² so a very even skin does not reject its
    own shading) and median / MAD of the log intensity (floored at 0.06). A fit to the
    whole face region minus features tolerates hair on < ~40 % of it."""
    p = _p68(points68)
    rgb = _rgb01(image)
    h, w = rgb.shape[:2]
    chrom, logi = _colour_features(rgb)
    sample = _sample_regions(p, (h, w)) if region is None else np.asarray(region, bool)
    c, li = chrom[sample].astype(np.float64), logi[sample].astype(np.float64)
    if len(c) < 20:
        raise BadInputError(f"too few skin pixels ({len(c)}) to fit a skin colour: is the face inside the image?")
    mu = np.median(c, 0)
    cov = np.eye(2) * 0.01**2
    keep = np.ones(len(c), bool)
    floor = np.eye(2) * 0.006**2
    for it in range(3):  # (the 2 x 2 algebra by hand: np.cov / einsum cost more than the fit on a small face)
        d = c - mu
        keep = _quadratic_form(d, _inv2(cov)) < 9.0 if it else _quadratic_form(d, np.eye(2)) < 0.04**2
        if np.count_nonzero(keep) < 20:
            keep = np.ones(len(c), bool)
        ck = c[keep]
        mu = ck.mean(0)
        dk = ck - mu
        cov = dk.T @ dk / max(len(ck) - 1, 1) + floor
    med = float(np.median(li[keep]))
    mad = max(1.4826 * float(np.median(np.abs(li[keep] - med))), 0.06)
    icov = _inv2(cov).astype(np.float32)
    d = chrom - mu.astype(np.float32)
    dist = np.sqrt(np.maximum(_quadratic_form(d, icov), 0)).astype(np.float32)
    z = ((logi - np.float32(med)) / np.float32(mad)).astype(np.float32)
    return dist, z


def beard_mask(image, points68, region, light, params: SkinParams = SkinParams()) -> np.ndarray:
    """bool (H, W): beard, stubble and hair strands on the lower face (below the nose tip).

    Hair is darker than the skin *and* rougher at a fine scale: the local energy of a
    σ = 0.006 × face-width high-pass of the luminance (blurred at 0.03 × face width) above
    ``beard_texture`` × its median over the face, where the blurred lightness z-score is
    below ``beard_dark``; closed, opened (thin strips of jaw shading go) and kept when
    larger than (0.08 × face width)². Chosen by looking at 18 FRL faces (6 bearded, 12 not)."""
    p = _p68(points68)
    img = _rgb01(image)
    fw = face_width(p)
    lum = img @ LUMA_BT601
    hp = lum - cv2.GaussianBlur(lum, (0, 0), 0.006 * fw)
    energy = cv2.GaussianBlur(hp * hp, (0, 0), 0.03 * fw)
    ref = float(np.median(energy[region])) if region.any() else float(np.median(energy))
    dark = cv2.GaussianBlur(light, (0, 0), 0.03 * fw) < params.beard_dark
    lower = np.zeros(region.shape, bool)
    lower[int(np.clip(p[30, 1], 0, region.shape[0])):] = True
    b = ((energy > params.beard_texture * max(ref, 1e-12)) & dark & lower).astype(np.uint8)
    b = cv2.morphologyEx(b, cv2.MORPH_CLOSE, disc(max(1, int(0.03 * fw))))
    b = cv2.morphologyEx(b, cv2.MORPH_OPEN, disc(max(1, int(0.035 * fw))))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(b, connectivity=8)
    keep = [i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= (0.08 * fw) ** 2]
    return np.isin(lab, keep) & region


def _fill_small_holes(mask: np.ndarray, max_area: float, lightness: np.ndarray | None = None) -> np.ndarray:
    """Small enclosed holes become skin — only bright ones (highlights) when ``lightness``
    (z-score) is given: a dark hole is a hair strand, a mole or a glasses frame."""
    inv = (~mask).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(inv, connectivity=4)
    out = mask.copy()
    for i in range(1, n):
        if stats[i, cv2.CC_STAT_AREA] <= max_area:
            x, y, ww, hh = stats[i, :4]
            touches = x == 0 or y == 0 or x + ww == mask.shape[1] or y + hh == mask.shape[0]
            if touches:
                continue
            hole = lab == i
            if lightness is None or float(np.median(lightness[hole])) > 0.0:
                out[hole] = True
    return out


