"""Issue 22, detail and not lighting: the skin's low-frequency colour change, hair and stubble
leaking in, how much skin changed, the marks kept and arrived, how far the detail moved."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import BadInputError
from ._detail import _abs_change, skin_detail
from ._paper import (
    PATCH_SIZE,
    SKIN_PATCHES,
    _as_points,
    _luminance,
    skin_patch_frames,
    working_scale,
)

# ---------------------------------------------------------------- issue 22: detail, not lighting
LOWFREQ_SIGMA = 0.1  # × the eye distance (eye centres): the blur of the low-frequency ΔE
CHANGED_LEVEL = 1.0  # 0–255: a skin pixel "changed" when its |Δ| blurred at σ = 2 px exceeds this
SPECK_SIGMA = 3.0  # px at 1000 px: a speck is darker than the luminance blurred at this σ …
SPECK_DEPTH = 0.04  # … by more than this (luminance 0..1)
SPECK_AREA = (2, 60)  # px at 1000 px: a speck's area (larger dark pieces are shadows or lips)
COHERENCE_RHO = 4.0  # px at 1000 px: integration σ of the structure tensor


def _content_skin(image, points68, skin):
    if skin is not None:
        m = np.asarray(skin, np.float32)
        if m.shape != np.asarray(image).shape[:2]:
            raise BadInputError(f"skin mask has shape {m.shape}, the image {np.asarray(image).shape[:2]}")
        return m
    from ..geometry.segment import skin_mask

    return skin_mask(np.asarray(image, np.float32), points68)


def _rgb01(image) -> np.ndarray:
    a = np.asarray(image, np.float32)
    if a.ndim != 3 or a.shape[2] < 3:
        raise BadInputError(f"expected an (H, W, 3) image, got shape {a.shape}")
    return a[..., :3] / 255.0 if a.max() > 1.5 else a[..., :3]


def lowfreq_skin_delta_e(output, content, points68, *, skin=None, sigma: float = LOWFREQ_SIGMA) -> dict:
    """ΔE76 (CIELAB, L 0..100) between ``output`` and ``content``, both low-passed at ``sigma`` ×
    the eye distance over the content's skin only (normalised convolution, so eyes, brows and
    hair never blur into it): ``mean`` over the skin (mask ≥ 0.5) and over each skin patch of
    :func:`skin_patch_frames` (``forehead``, ``left_cheek``, ``right_cheek``, and ``max_region``).
    ``skin``: the content's skin mask (default :func:`facetex.geometry.segment.skin_mask`)."""
    from ..geometry.filters import masked_lowpass
    from ..transfer.colour import eye_distance

    out, con = _rgb01(output), _rgb01(content)
    if out.shape != con.shape:
        raise BadInputError(f"images differ in shape: {out.shape} vs {con.shape}")
    p = _as_points(points68, "points68")
    m = _content_skin(con, p, skin)
    s = sigma * eye_distance(p)
    lab = [cv2.cvtColor(np.clip(masked_lowpass(x, m, s), 0, 1), cv2.COLOR_RGB2LAB) for x in (out, con)]
    de = np.sqrt(np.sum((lab[0] - lab[1]) ** 2, axis=2))
    inside = m >= 0.5
    res = {"mean": float(de[inside].mean()) if inside.any() else float("nan")}
    side = int(round(PATCH_SIZE / working_scale(con.shape)))
    for name, a in skin_patch_frames(p, con.shape).items():
        dp = cv2.warpAffine(de, a, (side, side), flags=cv2.INTER_NEAREST, borderValue=np.nan)
        mp = cv2.warpAffine(inside.astype(np.uint8), a, (side, side), flags=cv2.INTER_NEAREST) > 0
        res[name] = float(np.nanmean(dp[mp])) if mp.any() else float("nan")
    regions = [res[k] for k in SKIN_PATCHES if np.isfinite(res[k])]
    res["max_region"] = max(regions) if regions else float("nan")
    return res


def forehead_mask(points68, shape) -> np.ndarray:
    """bool (H, W): between the brows (points 17–26) and the forehead arc of
    :func:`facetex.geometry.masks.forehead_points`."""
    from ..geometry.masks import forehead_points

    p = _as_points(points68, "points68")
    poly = np.vstack([p[17:27], forehead_points(p)])
    m = np.zeros(shape[:2], np.uint8)
    cv2.fillPoly(m, [np.round(poly * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
    return m.astype(bool)


def structure_coherence(image, mask=None, *, rho: float = COHERENCE_RHO) -> float:
    """Energy-weighted mean coherence (λ1 − λ2) / (λ1 + λ2) of the structure tensor of a
    grey image (gradient σ 1 px, integration σ ``rho`` px) over ``mask``: 1 for parallel
    strands (hair), lower for isotropic texture (pores)."""
    from skimage.feature import structure_tensor, structure_tensor_eigenvalues

    img = np.asarray(image, np.float64)
    m = np.ones(img.shape, bool) if mask is None else np.asarray(mask, bool)
    if mask is not None and m.any():  # only the mask's box and the filters' reach: the same values, less memory
        pad = int(np.ceil(4 * float(rho))) + 4  # scipy's Gaussian reaches 4 sigma; np.gradient 1 px
        ys, xs = np.flatnonzero(m.any(axis=1)), np.flatnonzero(m.any(axis=0))
        y0, y1 = max(0, ys[0] - pad), min(img.shape[0], ys[-1] + 1 + pad)
        x0, x1 = max(0, xs[0] - pad), min(img.shape[1], xs[-1] + 1 + pad)
        img, m = img[y0:y1, x0:x1], m[y0:y1, x0:x1]
    a = structure_tensor(img, sigma=float(rho), order="rc", mode="reflect")
    l1, l2 = structure_tensor_eigenvalues(a)
    energy = l1 + l2
    coh = np.where(energy > 0, (l1 - l2) / np.where(energy > 0, energy, 1.0), 0.0)
    wsum = float(energy[m].sum())
    return float((coh[m] * energy[m]).sum() / wsum) if wsum > 0 else 0.0


def hair_leakage(output, content, points68, *, skin=None, rho: float = COHERENCE_RHO) -> float:
    """Structure-tensor coherence (:func:`structure_coherence`) of the luminance change
    ``output − content`` on the content's forehead skin: strands of the style's fringe make
    the change oriented (findings: 0.29 against 0.21–0.23 for pores alone)."""
    out, con = _rgb01(output), _rgb01(content)
    p = _as_points(points68, "points68")
    m = forehead_mask(p, con.shape) & (_content_skin(con, p, skin) >= 0.5)
    if not m.any():
        return float("nan")
    d = (_luminance(out) - _luminance(con)) * 255.0
    return structure_coherence(d, m, rho=rho / working_scale(con.shape))


def stubble_regions(points68, shape) -> dict[str, np.ndarray]:
    """bool (H, W) masks of the ``upper_lip`` (nostrils 31–35 down to the upper lip's edge
    48–54) and the ``chin`` (the lower lip's edge 54–59 down to the jaw 6–10, drawn 15 % of
    the way back towards the mouth so it stays off the chin's edge), minus the lips."""
    from ..geometry.masks import disc
    from ..geometry.skin import protected_mask

    p = _as_points(points68, "points68")
    h, w = shape[:2]
    mouth = p[48:60].mean(0)
    jaw = p[[6, 7, 8, 9, 10]]
    jaw = jaw + 0.15 * (mouth - jaw)
    polys = {"upper_lip": np.vstack([p[31:36], p[[54, 53, 52, 51, 50, 49, 48]]]),
             "chin": np.vstack([p[[54, 55, 56, 57, 58, 59, 48]], jaw])}
    lips = protected_mask(p, (h, w))
    r = max(1, int(round(0.01 * float(np.linalg.norm(p[16] - p[0])))))
    lips = cv2.dilate(lips.astype(np.uint8), disc(r)) > 0
    out = {}
    for k, poly in polys.items():
        m = np.zeros((h, w), np.uint8)
        cv2.fillPoly(m, [np.round(poly * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
        out[k] = (m > 0) & ~lips
    return out


def dark_speck_density(image, mask) -> float:
    """Dark specks per 1000 px of ``mask``: connected pieces (8-connected) at least
    ``SPECK_DEPTH`` darker than the luminance blurred at ``SPECK_SIGMA`` px, of
    ``SPECK_AREA`` px (lengths at 1000 px, scaled with the image) — stubble, stray hairs."""
    img = _rgb01(image)
    m = np.asarray(mask, bool)
    if m.shape != img.shape[:2]:
        raise BadInputError(f"mask has shape {m.shape}, the image {img.shape[:2]}")
    area = int(m.sum())
    if area == 0:
        return float("nan")
    k = 1.0 / working_scale(img.shape)
    lum = _luminance(img)
    dark = (cv2.GaussianBlur(lum, (0, 0), SPECK_SIGMA * k, borderType=cv2.BORDER_REFLECT) - lum > SPECK_DEPTH) & m
    n, lab, stats, _ = cv2.connectedComponentsWithStats(dark.astype(np.uint8), connectivity=8)
    a = stats[1:, cv2.CC_STAT_AREA]
    lo, hi = SPECK_AREA[0] * k * k, SPECK_AREA[1] * k * k
    return float(np.count_nonzero((a >= lo) & (a <= hi)) * 1000.0 / area)


def stubble_leakage(output, content, aligned_style, points68) -> dict:
    """Dark-speck density (:func:`dark_speck_density`) on the content's upper lip and chin
    (both together) of the ``output``, the ``content`` and the ``aligned_style`` (the style
    warped onto the content), and ``moved`` = (output − content) / (style − content): the
    fraction of the way to the style's stubble (NaN when the style has no more than the content)."""
    p = _as_points(points68, "points68")
    regions = stubble_regions(p, np.asarray(content).shape)
    m = regions["upper_lip"] | regions["chin"]
    d = {k: dark_speck_density(im, m) for k, im in (("output", output), ("content", content), ("style", aligned_style))}
    gap = d["style"] - d["content"]
    d["moved"] = (d["output"] - d["content"]) / gap if gap > 0.5 else float("nan")
    return d


def skin_coverage(output, content, points68, *, skin=None, level: float = CHANGED_LEVEL) -> float:
    """Fraction of the content's skin (mask ≥ 0.5) that changed: |output − content| (0–255,
    mean of the channels) blurred at σ = 2 px (at 1000 px) above ``level``."""
    p = _as_points(points68, "points68")
    m = _content_skin(_rgb01(content), p, skin) >= 0.5
    if not m.any():
        return float("nan")
    d = _abs_change(output, content)
    d = cv2.GaussianBlur(d, (0, 0), 2.0 / working_scale(d.shape), borderType=cv2.BORDER_REFLECT)
    return float(np.mean(d[m] > level))


def mark_survival(output, content, aligned_style, points68, *, skin=None, style_skin=None) -> dict:
    """The content's marks that survive in the output and the style's that arrive
    (:func:`facetex.geometry.marks.detect_marks`, dark blobs on the skin): counts
    ``content`` / ``style`` (the style's marks in the content frame, on the aligned style's own
    skin, that the content does not have there) and fractions ``kept`` / ``arrived``."""
    from ..geometry.marks import detect_marks, match_marks
    from ..geometry.masks import face_width
    from ..geometry.segment import skin_mask

    out, con, sty = _rgb01(output), _rgb01(content), _rgb01(aligned_style)
    p = _as_points(points68, "points68")
    mc = _content_skin(con, p, skin)
    ms = (skin_mask(sty, p) if style_skin is None else np.asarray(style_skin, np.float32)) * (mc > 0.05)
    fw = face_width(p)
    mk_c = detect_marks(con, mc, face_width=fw)
    mk_s = detect_marks(sty, ms, face_width=fw)
    mk_s = mk_s[~match_marks(mk_s, mk_c)]
    mk_o = detect_marks(out, mc, face_width=fw)
    kept = match_marks(mk_c, mk_o)
    arrived = match_marks(mk_s, mk_o)
    return {"content": int(len(mk_c)), "style": int(len(mk_s)),
            "kept": float(kept.mean()) if len(mk_c) else float("nan"),
            "arrived": float(arrived.mean()) if len(mk_s) else float("nan")}


def detail_moved(output, content, style, points_output, points_content, points_style, *, skins=None) -> dict:
    """Fraction of the way the fine skin detail (:func:`skin_detail`, per patch) moved from
    the content's level to the style's own: (d_out − d_con) / (d_sty − d_con), NaN where the two
    differ by < 0.1 (0–255). ``mean`` over the patches; ``cheeks_rougher`` over the cheeks
    where the style is rougher than the content (NaN when none is).

    ``skins`` = (content skin, style skin), (H, W) masks of the content and the style image:
    ``cheeks_rougher_skin`` is the same measure over the skin pixels of the patches only — the
    output and the content on the content's skin, the style on its source skin (no moustache,
    stubble, hair or highlights). The whole cheek patch reaches the nostril and the moustache's
    corner, so on a bearded style ``cheeks_rougher`` also measures the beard, which the
    transfer must not copy (issue 22)."""
    _, do = skin_detail(output, points_output, per_patch=True)
    _, dc = skin_detail(content, points_content, per_patch=True)
    _, ds = skin_detail(style, points_style, per_patch=True)
    res = {}
    for k in SKIN_PATCHES:
        gap = ds[k] - dc[k]
        res[k] = (do[k] - dc[k]) / gap if abs(gap) >= 0.1 else float("nan")
    vals = [res[k] for k in SKIN_PATCHES if np.isfinite(res[k])]
    res["mean"] = float(np.mean(vals)) if vals else float("nan")
    res["cheeks_rougher"] = _rougher_cheeks(do, dc, ds)
    if skins is not None:
        _, do_s = skin_detail(output, points_content, per_patch=True, mask=skins[0])
        _, dc_s = skin_detail(content, points_content, per_patch=True, mask=skins[0])
        _, ds_s = skin_detail(style, points_style, per_patch=True, mask=skins[1])
        res["cheeks_rougher_skin"] = _rougher_cheeks(do_s, dc_s, ds_s)
    return res


def _rougher_cheeks(do, dc, ds) -> float:
    """Mean fraction moved over the cheeks where the style is rougher by > 0.1 (NaN: none)."""
    rough = [(do[k] - dc[k]) / (ds[k] - dc[k]) for k in ("left_cheek", "right_cheek")
             if np.isfinite(ds[k]) and np.isfinite(dc[k]) and np.isfinite(do[k]) and ds[k] > dc[k] + 0.1]
    return float(np.mean(rough)) if rough else float("nan")
