"""Native-resolution skin detail stage (beyond the FaceTex paper): pure numpy / OpenCV.

The CNN optimisation works at a few hundred pixels, where pores (2–4 px on a 1000 px
portrait) cannot be represented, and the pre-warp resamples the style. This stage puts
the *style's own* fine detail into the content's skin at the output's resolution:

1. split the optimised output and the aligned style into difference-of-Gaussian bands
   ``B_k = G_{σ_{k-1}} − G_{σ_k}`` (σ = 0, 1, 2, 4, 8 px at the 330 px reference face width,
   scaled with the face), the rest of the output (coarser than σ = 8) stays as optimised;
2. local band energies ``E_k = G_{2σ_k} * B_k²`` (Shih et al. 2014, "Style Transfer for
   Headshot Portraits", §4: local energy of a Laplacian stack, blurred at twice the band's
   scale). The style's energy is measured in the style photo itself and carried into the
   content frame with the pre-warp's map (a smooth map carries a smooth energy faithfully,
   while resampling the bands themselves loses energy at pore scale);
3. where both faces show skin (``content_skin × style_skin``) the output's band becomes
   the aligned style's band scaled by ``sqrt(E_style / E_aligned)`` (the gain restores what
   the resampling lost, clipped to ``gain_range``); where the content shows skin but the
   aligned style does not (its hair, eyes or a warp's edge land there), the output keeps
   its own band scaled to the style's median skin energy (Shih's gain with a global target),
   so no hair or feature of the style is copied (that gain is capped at 1.25: more turns the
   optimiser's faint swirls into visible worms). Style skin whose fine detail is several
   times rougher than its typical skin (stubble at a beard's edge, stray hairs, a mole's
   rim: what the colour mask misses) is treated as not skin. With ``fill`` (default) the
   style's non-skin there is first filled from its own skin (:func:`fill_from_source`:
   mirrored across thin gaps, random blended pieces in large holes), so those places get the style's skin detail too, never its hair or beard.
   The style's bands are scaled by the ratio of the two faces' local colours (``relative``):
   skin texture modulates reflectance, so the output takes the style's contrast, not its
   amplitude (a pale style's bands added as they were mottled a dark face grey).
   Only the bands up to ``fill_max_sigma`` are filled: the coarsest band's pieces carry fine lines
   and folds, laid across the hole as dark strokes; there the output keeps its own band.
   In ``own_zone`` (the pipeline passes the content's beard zone: upper lip and chin)
   the output keeps its own detail as it is: the style's plain pores copied there
   read as stubble specks on a clean-shaven face (FRL 087 ← 067, issue 22).

Everything outside the content's skin is returned untouched. Hand-written (no library
does band-energy transfer between two aligned images).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import BadInputError
from ..io import LUMA_BT601

__all__ = ["DetailParams", "band_stack", "band_energy", "transfer_skin_detail", "style_band_energies",
           "fill_from_source", "REF_FACE_WIDTH"]

#: face width |p16 − p0| (px) at which :attr:`DetailParams.sigmas` are given (FRL, 1000 px)
REF_FACE_WIDTH = 330.0


@dataclass(frozen=True)
class DetailParams:
    """Parameters of :func:`transfer_skin_detail` (lengths in px at REF_FACE_WIDTH)."""

    # band edges [0,1], [1,2], [2,4], [4,8] px: pores, fine lines, freckles and blemishes; the
    # [4,8] band moved S(xt,xs) by +0.012 on 5 FRL pairs (identity distance +0.05), coarser
    # bands carry the face's own shading (docs/facetex-fidelity.md)
    sigmas: tuple[float, ...] = (1.0, 2.0, 4.0, 8.0)
    energy_scale: float = 2.0  # energy blur = energy_scale × the band's outer sigma
    gain_range: tuple[float, float] = (0.5, 3.0)  # of the style's bands (restores resampling losses)
    rough_lo: float = 3.0  # style detail up to this × its median skin energy is skin texture
    rough_hi: float = 8.0  # from this × on it is stubble / hair / an edge: not copied
    own_gain_range: tuple[float, float] = (0.5, 1.25)  # of the output's own bands where the style is not skin:
    # more amplifies the optimiser's faint swirl pattern into visible worms (seen on FRL 083←005)
    eps: float = 1e-6  # energy floor (values in [0, 1]²)
    fill: bool = True  # fill the style's non-skin (hair, beard, highlights) from its skin, not from the output
    # the fill reaches the bands up to this outer sigma only: pieces of the style's [4, 8] band
    # are fine lines and folds, which the fill laid across a cheek as dark strokes (FRL 042 <- 003);
    # pores and grain (finer bands) fill without a trace, coarser holes keep the output's own band
    fill_max_sigma: float = 4.0
    strength: float = 1.0  # 0 = output unchanged, 1 = full style detail
    # the style's detail is scaled by (output's local colour / style's local skin colour) ** relative,
    # per channel: skin texture modulates reflectance, so a pore keeps its contrast, not its
    # amplitude, on a darker or lighter face (added as it was, a pale style's freckles and
    # capillaries turned FRL 042 mottled and ashen); 0 = added as it is. Never amplified (at most 1):
    # a darker photo's fine bands carry more of its noise and JPEG blocks, which doubled became a
    # lumpy orange-peel on a pale face (FRL 068 <- 096)
    relative: float = 1.0
    relative_range: tuple[float, float] = (0.25, 1.0)


def _gauss(img: np.ndarray, sigma: float) -> np.ndarray:
    if sigma <= 0:
        return img
    return cv2.GaussianBlur(img, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)


def _luma(img: np.ndarray) -> np.ndarray:
    return img @ LUMA_BT601 if img.ndim == 3 else img


def band_stack(image: np.ndarray, sigmas) -> tuple[list[np.ndarray], np.ndarray]:
    """Difference-of-Gaussian bands [I − G_σ1, G_σ1 − G_σ2, ...] and the residual G_σn;
    they sum back to ``image`` exactly."""
    img = np.asarray(image, np.float32)
    bands, prev = [], img
    for s in sigmas:
        g = _gauss(img, float(s))
        bands.append(prev - g)
        prev = g
    return bands, prev


def band_energy(band: np.ndarray, sigma: float) -> np.ndarray:
    """Local energy of a band: Gaussian (``sigma``) blur of its squared luminance."""
    b = _luma(np.asarray(band, np.float32))
    return _gauss(b * b, sigma)


def _check(name, a, shape=None, channels=None) -> np.ndarray:
    a = np.asarray(a, np.float32)
    if shape is not None and a.shape[:2] != tuple(shape):
        raise BadInputError(f"{name} has shape {a.shape[:2]}, expected {tuple(shape)}")
    if channels is not None and (a.ndim != 3 or a.shape[2] != channels):
        raise BadInputError(f"{name} must be (H, W, {channels}), got {a.shape}")
    return a


def transfer_skin_detail(output, aligned_style, content_skin, style_skin, *, style_energy=None,
                         face_width: float = REF_FACE_WIDTH, params: DetailParams = DetailParams(),
                         own_zone=None, own_detail=None, return_info: bool = False):
    """Give ``output`` the style's fine skin detail at its own resolution (see module doc).

    ``output``, ``aligned_style``: (H, W, 3) float in [0, 1], the same geometry;
    ``content_skin``, ``style_skin``: (H, W) in [0, 1] (the style's skin mask warped into
    this frame); ``style_energy``: list of (H, W) target energies per band (from
    :func:`style_band_energies` in the style photo, warped here), default the aligned
    style's own; ``face_width``: of the content face in these pixels (scales ``sigmas``).
    ``own_zone`` (H, W) bool: where the output keeps its own detail as it is, neither the
    style's nor a fill's — the content's beard zone: any pore of the style copied there reads
    as a stubble speck, and a gain towards a smoother style would erase the content's stubble.
    ``own_detail`` (H, W, 3) or None: the image whose detail bands the zone takes (the pipeline
    passes the content): the optimiser's own bands there carried a purple/green chroma speckle
    and a faded moustache (FRL 042 ← 003); None keeps ``output``'s.
    Returns the new image (and with ``return_info`` a dict of per-band mean gains).
    """
    out = _check("output", output, channels=3)
    hw = out.shape[:2]
    sty = _check("aligned_style", aligned_style, hw, 3)
    mc = np.clip(_check("content_skin", content_skin, hw), 0, 1)
    ms = np.clip(_check("style_skin", style_skin, hw), 0, 1)
    scale = float(face_width) / REF_FACE_WIDTH
    sig = [s * scale for s in params.sigmas]
    b_out, _ = band_stack(out, sig)
    b_sty, _ = band_stack(sty, sig)
    if style_energy is not None and len(style_energy) != len(sig):
        raise BadInputError(f"style_energy has {len(style_energy)} bands, expected {len(sig)}")
    lo, hi = params.gain_range
    e_aligned = [band_energy(b, params.energy_scale * s) for b, s in zip(b_sty, sig)]
    e_targets = e_aligned if style_energy is None else [np.asarray(e, np.float32) for e in style_energy]
    skin = (mc > 0.5) & (ms > 0.5)
    ms = ms * _smooth_roughness_gate(e_targets, skin, max(sig), params)
    own = np.zeros(hw, bool) if own_zone is None else _check("own_zone", own_zone, hw) > 0
    own_soft = np.zeros(hw, np.float32)
    b_own = b_out
    if own.any() and own_detail is not None:
        b_own, _ = band_stack(_check("own_detail", own_detail, hw, 3), sig)
    if own.any():  # feathered like the skin masks, so the zone leaves no seam
        own_soft = np.clip(_gauss(own.astype(np.float32), 0.01 * float(face_width)), 0, 1)
        ms = ms * (1.0 - own_soft)
    skin = (mc > 0.5) & (ms > 0.5)
    src_skin = ms > 0.5  # the style's own skin, before any fill
    ms_band = [ms] * len(sig)  # per band: where the style's (or its fill's) band is copied
    e_targets = list(e_targets)
    if params.fill and skin.sum() >= 64 and ((mc > 0) & (ms < 0.5) & ~own).any():
        # what the style's hair, beard, highlights or features cover is filled from its own
        # skin (mirrored across the nearest skin edge), so the content's skin there gets
        # the style's skin detail, never its hair (issue 22)
        # the bands, not the pixels: copied pieces of a band carry no step in brightness
        fine = [k for k, s0 in enumerate(params.sigmas) if s0 <= params.fill_max_sigma]
        filled = fill_from_source([b_sty[k] for k in fine], src_skin, (mc > 0) & ~src_skin & ~own,
                                  block=max(8, int(round(0.1 * float(face_width)))), mirror_max=0.03 * float(face_width))
        ms_filled = np.where((mc > 0) & ~own, 1.0, ms).astype(np.float32)
        for k, b in zip(fine, filled):
            b_sty[k] = b
            e_aligned[k] = band_energy(b, params.energy_scale * sig[k])
            e_targets[k] = np.where(src_skin, e_targets[k], e_aligned[k])
            ms_band[k] = ms_filled
    skin_band = [(mc > 0.5) & (m > 0.5) for m in ms_band]
    ratio, ratio_l = _colour_ratio(out, sty, src_skin, 2.0 * max(sig), params)
    result = out.copy()
    info = {"gain_style": [], "gain_own": [], "style_skin_rough_fraction": float(
        np.mean(ms[(mc > 0.5)] < 0.5)) if (mc > 0.5).any() else 0.0}
    for k, s in enumerate(sig):
        es = params.energy_scale * s
        both = (mc * ms_band[k])[..., None]
        only_content = (mc * (1.0 - ms_band[k]))[..., None]
        e_target = e_targets[k]
        g_style = np.clip(np.sqrt((e_target + params.eps) / (e_aligned[k] + params.eps)), lo, hi)
        # the style's typical skin energy in this band, for places its warped image is not skin
        sk = skin_band[k]
        ref = float(np.median(e_target[sk])) if sk.any() else float(np.median(e_target))
        e_out = band_energy(b_out[k], es)
        g_own = np.clip(np.sqrt((ref * ratio_l ** 2 + params.eps) / (e_out + params.eps)), *params.own_gain_range)
        # in the zone the own detail as it is: a gain towards a smoother style would erase stubble
        own_k = (1.0 - own_soft)[..., None] * g_own[..., None] * b_out[k] + own_soft[..., None] * b_own[k]
        new = both * (g_style[..., None] * ratio * b_sty[k]) + only_content * own_k + (1.0 - mc[..., None]) * b_out[k]
        result += params.strength * (new - b_out[k])
        if sk.any():
            info["gain_style"].append(float(np.median(g_style[sk])))
        if (mc > 0.5).any():
            info["gain_own"].append(float(np.median(g_own[mc > 0.5])))
    result = np.clip(result, 0.0, 1.0)
    return (result, info) if return_info else result


def _colour_ratio(out, sty, style_skin, sigma, params: DetailParams):
    """((H, W, 3), (H, W)): (local colour of ``out`` / the style's local skin colour) **
    ``params.relative`` per channel and in luminance, clipped to ``relative_range``. The style's
    colour is a masked blur over its own skin (its hair, brows or background do not count; far
    from any skin: the median skin colour)."""
    h, w = out.shape[:2]
    if params.relative == 0 or style_skin.sum() < 16:
        return np.ones((h, w, 1), np.float32), np.ones((h, w), np.float32)
    lo_o = _gauss(out, sigma)
    m = style_skin.astype(np.float32)
    wsum = _gauss(m, sigma)[..., None]
    median = np.median(sty[style_skin], axis=0).astype(np.float32)
    lo_s = _gauss(sty * m[..., None], sigma) + np.clip(0.05 - wsum, 0, None) * median
    lo_s = lo_s / np.maximum(wsum + np.clip(0.05 - wsum, 0, None), 1e-6)
    lo, hi = params.relative_range
    ratio = np.clip((lo_o / np.maximum(lo_s, 1e-3)) ** params.relative, lo, hi).astype(np.float32)
    ratio_l = np.clip((_luma(lo_o) / np.maximum(_luma(lo_s), 1e-3)) ** params.relative, lo, hi).astype(np.float32)
    return ratio, ratio_l


def fill_from_source(images, source: np.ndarray, holes: np.ndarray, *, block: int = 32, mirror_max: float = 10.0,
                     seed: int = 0) -> list[np.ndarray]:
    """``images`` (same-shape arrays, e.g. the bands of one image) with their ``holes`` pixels
    filled from their ``source`` pixels. A hole pixel within ``mirror_max`` px of the source
    takes the mirror 2q − p of its nearest source pixel q when that is source (the texture
    goes on across a thin gap). Deeper pixels get ``block``-sized pieces of the source, drawn
    at random among the 4 × ``block`` nearest plain ones (no busier than the median piece: no
    wrinkle or mole is copied), overlapping by half and blended with weights w/√Σw² (Hann windows), which
    keeps the energy of uncorrelated texture: no block edges, no repeating pattern (a
    mirror-tiled patch showed a kaleidoscope lattice on a fringe-covered forehead). Meant
    for zero-mean detail bands; pixels outside ``holes`` are returned unchanged."""
    from scipy.ndimage import distance_transform_edt

    src = np.asarray(source, bool)
    h, w = src.shape
    todo = np.asarray(holes, bool) & ~src
    imgs = [np.asarray(im, np.float32).copy() for im in images]
    if not todo.any() or src.sum() < 4:
        return imgs
    dist, (qy, qx) = distance_transform_edt(~src, return_indices=True)
    py, px = np.nonzero(todo)
    my, mx = 2 * qy[py, px] - py, 2 * qx[py, px] - px
    near = (dist[py, px] <= mirror_max) & (my >= 0) & (my < h) & (mx >= 0) & (mx < w)
    near[near] = src[my[near], mx[near]]
    deep = todo.copy()
    deep[py[near], px[near]] = False
    for im in imgs:
        im[py[near], px[near]] = im[my[near], mx[near]]
    if not deep.any():
        return imgs
    # block origins that lie (almost) wholly in the source; small sources fall back to any source pixel
    b = int(max(4, min(block, h, w)))
    cover = cv2.boxFilter(src.astype(np.float32), -1, (b, b), normalize=True, anchor=(0, 0), borderType=cv2.BORDER_CONSTANT)
    cy, cx = np.nonzero(cover[: h - b + 1, : w - b + 1] > 0.97)
    if len(cy) == 0:
        cy, cx = np.nonzero(cover[: h - b + 1, : w - b + 1] >= cover[: h - b + 1, : w - b + 1].max() - 1e-6)
    # plain skin only: blocks at most as busy as the median block (a wrinkle, a mole or a scar
    # copied into the hole would be a new mark there)
    busy = sum(cv2.boxFilter((im * im).sum(-1) if im.ndim == 3 else im * im, -1, (b, b), anchor=(0, 0),
                             borderType=cv2.BORDER_CONSTANT) for im in imgs)[cy, cx]
    keep = busy <= np.median(busy)
    cy, cx = cy[keep], cx[keep]
    # and near the hole: each block draws from the nearest candidates (the same part of the face)
    from scipy.spatial import cKDTree

    tree = cKDTree(np.column_stack([cy, cx]))
    near_k = int(min(len(cy), max(8, 4 * b)))
    rng = np.random.default_rng(seed)
    win = np.outer(np.hanning(b + 2)[1:-1], np.hanning(b + 2)[1:-1]).astype(np.float32)
    acc = [np.zeros_like(im) for im in imgs]
    wsum = np.zeros((h, w), np.float32)
    ys, xs = np.nonzero(deep)
    step = b // 2
    for y0 in range((ys.min() // step) * step - step, ys.max() + 1, step):
        for x0 in range((xs.min() // step) * step - step, xs.max() + 1, step):
            ty0, tx0, ty1, tx1 = max(y0, 0), max(x0, 0), min(y0 + b, h), min(x0 + b, w)
            if ty1 <= ty0 or tx1 <= tx0 or not deep[ty0:ty1, tx0:tx1].any():
                continue
            _, cand = tree.query([y0, x0], k=near_k)
            k = int(np.atleast_1d(cand)[rng.integers(near_k)])
            sy, sx = cy[k] + (ty0 - y0), cx[k] + (tx0 - x0)
            wv = win[ty0 - y0:ty1 - y0, tx0 - x0:tx1 - x0]
            for a, im in zip(acc, imgs):
                piece = im[sy:sy + (ty1 - ty0), sx:sx + (tx1 - tx0)]
                a[ty0:ty1, tx0:tx1] += (wv[..., None] if im.ndim == 3 else wv) * piece
            wsum[ty0:ty1, tx0:tx1] += wv * wv
    norm = 1.0 / np.sqrt(np.maximum(wsum, 1e-6))
    for a, im in zip(acc, imgs):
        v = a * (norm[..., None] if im.ndim == 3 else norm)
        im[deep] = v[deep]
    return imgs


def _smooth_roughness_gate(energies, skin, sigma, params: DetailParams) -> np.ndarray:
    """(H, W) in [0, 1]: 1 where the style's fine detail is as rough as its typical skin, 0
    where it is ``rough_hi`` × rougher (stubble, stray hairs, a mole's edge, a warp's tear:
    things a colour mask misses and that would be copied as speckles), log-linear between
    ``rough_lo`` and ``rough_hi``, blurred over twice the coarsest band."""
    total = sum(energies)
    ref = float(np.median(total[skin])) if skin.any() else float(np.median(total))
    r = np.log(np.maximum(total, 1e-12) / max(ref, 1e-12))
    lo, hi = np.log(params.rough_lo), np.log(params.rough_hi)
    gate = np.clip((hi - r) / (hi - lo), 0.0, 1.0).astype(np.float32)
    return np.clip(_gauss(gate, 2.0 * sigma), 0.0, 1.0)


def style_band_energies(style, *, face_width: float, params: DetailParams = DetailParams()) -> list[np.ndarray]:
    """Local band energies of the style photo in its own frame, bands scaled to the style's
    ``face_width`` (so band k covers the same facial scale in both faces); warp them into
    the content frame with the pre-warp's map."""
    img = _check("style", style, channels=3)
    sig = [s * float(face_width) / REF_FACE_WIDTH for s in params.sigmas]
    bands, _ = band_stack(img, sig)
    return [band_energy(b, params.energy_scale * s) for b, s in zip(bands, sig)]
