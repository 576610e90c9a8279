"""Face segmentation into skin, hair, brows, beard/stubble, highlights and features (issue 22's
skin-only style source; see :mod:`facetex.geometry.skin` for the colour model it builds on)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..io import LUMA_BT601
from .masks import disc, face_width
from .skin import _BROWS, SkinParams, _dilate, _fill_small_holes, _p68, _poly, _rgb01, _sample_regions, _shape, beard_mask, face_region_mask, feature_mask, skin_colour_distance

__all__ = [
    "LABELS",
    "head_region_mask",
    "structure_tensor",
    "hair_strand_mask",
    "dark_speck_density",
    "stubble_mask",
    "highlight_mask",
    "beard_zone_mask",
    "FaceSegmentation",
    "segment_face",
    "skin_mask",
]


# ---------------------------------------------------------------- segmentation
#: label values of :func:`segment_face`
LABELS = {"other": 0, "skin": 1, "hair": 2, "brow": 3, "beard": 4, "highlight": 5, "feature": 6}


def head_region_mask(points68, shape, *, mesh=None, params: SkinParams = SkinParams()) -> np.ndarray:
    """bool (H, W): where the face's skin may lie — the face region (:func:`face_region_mask`)
    with the jaw pushed out by ``jaw_grow`` × face width (the jaw edge) and a tall forehead
    arc (``head_ratio`` × brow-to-nose-base above the brows), so the temples and the upper
    forehead up to any hairline are inside; the colour and hair tests find the hairline."""
    from .masks import forehead_points

    p, (h, w) = _p68(points68), _shape(shape)
    fw = face_width(p)
    o = (p[0] + p[16]) / 2
    jaw = p[:17] + (p[:17] - o) / np.linalg.norm(p[:17] - o, axis=1, keepdims=True) * params.jaw_grow * fw
    out = np.zeros((h, w), np.uint8)
    _poly(out, np.vstack([jaw, forehead_points(p, 21, ratio=params.head_ratio)]))
    face = face_region_mask(p, (h, w), mesh=mesh, shrink=0.0)
    grown = _dilate(face.astype(np.uint8), params.jaw_grow * fw)
    return (out > 0) | (grown > 0)


def structure_tensor(lum: np.ndarray, sigma: float, rho: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(energy λ1 + λ2, coherence ((λ1 − λ2)/(λ1 + λ2))², edge consistency) of the structure
    tensor J = G_ρ * (∇I_σ ∇I_σᵀ) (Bigün & Granlund 1987). Hair strands are high-energy and
    coherent (one orientation), pores and skin grain are not; edge consistency
    |G_ρ * ∇I_σ| / G_ρ * |∇I_σ| is near 1 at a step edge (a silhouette, a nostril's rim:
    every gradient points the same way) and low across strands (thin lines flip it)."""
    g = cv2.GaussianBlur(lum, (0, 0), max(sigma, 0.3))
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    jxx = cv2.GaussianBlur(gx * gx, (0, 0), rho)
    jyy = cv2.GaussianBlur(gy * gy, (0, 0), rho)
    jxy = cv2.GaussianBlur(gx * gy, (0, 0), rho)
    tr = jxx + jyy
    diff = np.sqrt((jxx - jyy) ** 2 + 4 * jxy * jxy)  # λ1 − λ2
    coh = (diff / (tr + 1e-12)) ** 2
    mean = np.sqrt(cv2.GaussianBlur(gx, (0, 0), rho) ** 2 + cv2.GaussianBlur(gy, (0, 0), rho) ** 2)
    edge = mean / (cv2.GaussianBlur(np.sqrt(gx * gx + gy * gy), (0, 0), rho) + 1e-12)
    return tr.astype(np.float32), coh.astype(np.float32), edge.astype(np.float32)


def _luma01(img: np.ndarray) -> np.ndarray:
    return (img @ LUMA_BT601).astype(np.float32)


def hair_strand_mask(image, points68, region, reference, params: SkinParams = SkinParams(), *,
                     exclude=None) -> np.ndarray:
    """bool (H, W): hair strands of skin-like colour (a blond fringe, stray locks) inside
    ``region`` minus ``exclude``: structure-tensor energy above ``strand_energy`` × its
    median on the ``reference`` skin, coherence above ``strand_coherence`` and edge
    consistency below ``strand_edge`` (σ = 0.003, ρ = 0.012 × face width; see
    :func:`structure_tensor`), closed over a strand spacing; only pieces rising above the
    brows or reaching the region's outer border count (hair comes from outside the face)."""
    p = _p68(points68)
    img = _rgb01(image)
    fw = face_width(p)
    region = np.asarray(region, bool)
    energy, coh, edge = structure_tensor(_luma01(img), 0.003 * fw, 0.012 * fw)
    ref = float(np.median(energy[reference])) if reference.any() else float(np.median(energy[region]))
    s = (energy > params.strand_energy * max(ref, 1e-12)) & (coh > params.strand_coherence) \
        & (edge < params.strand_edge) & region
    if exclude is not None:
        s &= ~np.asarray(exclude, bool)
    s = cv2.morphologyEx(s.astype(np.uint8), cv2.MORPH_CLOSE, disc(max(1, int(0.015 * fw))))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(s, connectivity=8)
    border = region & ~(cv2.erode(region.astype(np.uint8), disc(max(1, int(0.02 * fw)))) > 0)
    touching = set(np.unique(lab[border & (s > 0)]).tolist())
    top = float(p[17:27, 1].min())
    keep = [i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= (0.03 * fw) ** 2
            and (i in touching or stats[i, cv2.CC_STAT_TOP] < top)]
    return np.isin(lab, keep)


def dark_speck_density(image, face_w: float, *, threshold=None, reference=None, within=None) -> tuple[np.ndarray, float]:
    """(density, threshold): the fraction of pixels, in a Gaussian window of 0.03 × face
    width, that are darker than their surround (blur σ = 0.01 × face width) by more than
    ``threshold`` (default 3 robust σ of that darkness on ``reference``, floored at 0.02):
    stubble and beard hairs as dark specks. ``within`` (bool): only these pixels count, as
    specks and as surround (normalised blur), so a silhouette or a shadow's edge is none."""
    lum = _luma01(_rgb01(image))
    s1, s2 = 0.01 * face_w, 0.03 * face_w
    if within is None:
        w = np.ones(lum.shape, np.float32)
    else:
        w = np.asarray(within, np.float32)
    surround = cv2.GaussianBlur(lum * w, (0, 0), s1) / (cv2.GaussianBlur(w, (0, 0), s1) + 1e-6)
    d = surround - lum
    if threshold is None:
        vals = d[reference] if reference is not None and reference.any() else d[w > 0]
        med = float(np.median(vals))
        threshold = max(med + 3.0 * 1.4826 * float(np.median(np.abs(vals - med))), 0.02)
    speck = ((d > threshold) & (w > 0)).astype(np.float32)
    dens = cv2.GaussianBlur(speck, (0, 0), s2) / (cv2.GaussianBlur(w, (0, 0), s2) + 1e-6)
    return np.where(w > 0, dens, 0).astype(np.float32), float(threshold)


def stubble_mask(image, points68, region, reference, params: SkinParams = SkinParams(), *,
                 exclude=None) -> np.ndarray:
    """bool (H, W): stubble and beard on the lower face and jaw (below the eyes): dark-speck
    density (:func:`dark_speck_density`, counted in ``region``) above ``stubble_density``
    and above ``stubble_ratio`` × its median on the ``reference`` skin (nose bridge, under
    the eyes: bare on nearly every face), not within 0.025 × face width of ``exclude``
    (nostril and lip shadows); opened and kept above (0.07 × face width)² (alar creases go)."""
    p = _p68(points68)
    fw = face_width(p)
    region = np.asarray(region, bool)
    dens, _ = dark_speck_density(image, fw, reference=reference, within=region)
    ref = float(np.median(dens[reference])) if reference.any() else 0.0
    lower = np.zeros(region.shape, bool)
    lower[int(np.clip(p[41:48, 1].max() + 0.05 * fw, 0, region.shape[0])):] = True
    b = (dens > max(params.stubble_density, params.stubble_ratio * ref)) & lower & region
    if exclude is not None:
        b &= ~(_dilate(np.asarray(exclude, np.uint8), 0.025 * fw) > 0)
    b = cv2.morphologyEx(b.astype(np.uint8), cv2.MORPH_OPEN, disc(max(1, int(0.015 * fw))))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(b, connectivity=8)
    keep = [i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= (0.07 * fw) ** 2]
    return np.isin(lab, keep)


def highlight_mask(image, region, light, params: SkinParams = SkinParams(), face_w: float = 330.0) -> np.ndarray:
    """bool (H, W): specular highlights in ``region`` — brighter than the skin by
    ``highlight_sigmas`` (log-intensity z-score ``light``) and less saturated than its
    median skin saturation × ``highlight_chroma`` (white light reflected at the surface,
    not skin colour); grown by 0.01 × face width (their soft rim)."""
    img = _rgb01(image)
    mx, mn = img.max(-1), img.min(-1)
    sat = (mx - mn) / (mx + 1e-3)
    base = region & (np.abs(light) < 1.0)
    s0 = float(np.median(sat[base])) if base.any() else float(np.median(sat[region]))
    zb = cv2.GaussianBlur(light, (0, 0), 0.003 * face_w)
    sb = cv2.GaussianBlur(sat, (0, 0), 0.003 * face_w)
    h = (zb > params.highlight_sigmas) & (sb < params.highlight_chroma * s0) & region
    return (_dilate(h.astype(np.uint8), 0.01 * face_w) > 0) & region


def _reference_skin(p: np.ndarray, shape) -> np.ndarray:
    """bool (H, W): nose bridge and the cheeks just under the eyes — bare skin on nearly
    every face (no beard, no fringe)."""
    h, w = shape
    fw = face_width(p)
    m = np.zeros((h, w), np.uint8)
    r = max(2, int(round(0.05 * fw)))
    for eye, side in ((range(36, 42), 1), (range(42, 48), 15)):
        c = p[list(eye)].mean(0) * 0.4 + (p[side] + p[30]) / 2 * 0.6
        cv2.circle(m, (int(round(c[0])), int(round(c[1]))), r, 1, -1)
    cv2.line(m, tuple(np.round(p[28]).astype(int)), tuple(np.round(p[30]).astype(int)), 1,
             max(1, int(round(0.05 * fw))))
    return m.astype(bool)


def beard_zone_mask(points68, shape, params: SkinParams = SkinParams()) -> np.ndarray:
    """bool (H, W): where a moustache and a goatee grow — the convex hull of the nose base
    (31–35), the mouth (48–59) and the chin's jaw (6–10), grown by ``beard_zone_margin`` × face
    width: the upper lip and the chin, by geometry alone (stubble there may be invisible to
    colour and dark-speck tests). It stops short of the cheeks (with the jaw points 5 and 11 it
    took 8–14 % of the cheek patches, where the style's detail should arrive)."""
    p, (h, w) = _p68(points68), _shape(shape)
    hull = cv2.convexHull(np.vstack([p[31:36], p[48:60], p[6:11]]).astype(np.float32))[:, 0]
    m = np.zeros((h, w), np.uint8)
    _poly(m, hull)
    return _dilate(m, params.beard_zone_margin * face_width(p)) > 0


@dataclass
class FaceSegmentation:
    """Labels of :func:`segment_face` and its bool parts, all (H, W)."""

    labels: np.ndarray  # uint8, values of LABELS
    skin: np.ndarray  # the whole skin (highlights included): where the content may change
    hair: np.ndarray
    brows: np.ndarray
    beard: np.ndarray
    highlight: np.ndarray
    features: np.ndarray  # grown eyes, brows, lips, nostrils
    region: np.ndarray  # head region searched
    speckled: np.ndarray  # skin with sparse stubble-like dark specks (not a texture source)
    beard_zone: np.ndarray | None = None  # upper lip and chin (not a texture source)

    def source(self, margin: float, face_w: float) -> np.ndarray:
        """bool: skin that may be a texture source — the skin minus highlights, and at least
        ``margin`` × face width away from hair and beard (strand tips, a beard's fading edge),
        minus skin speckled like stubble (``source_speck``) and the beard zone."""
        bad = (self.hair | self.beard).astype(np.uint8)
        bad = _dilate(bad, margin * face_w) > 0
        src = self.skin & ~bad & ~self.highlight & ~self.speckled
        return src if self.beard_zone is None else src & ~self.beard_zone

    def padded(self, shape, origin) -> "FaceSegmentation":
        """The segmentation of a crop placed at ``origin`` (y, x) in an image of ``shape``."""
        y, x = origin
        def put(a):
            if a is None:
                return None
            out = np.zeros(tuple(shape[:2]), a.dtype)
            out[y:y + a.shape[0], x:x + a.shape[1]] = a
            return out
        return FaceSegmentation(**{k: put(getattr(self, k)) for k in self.__dataclass_fields__})


def segment_face(image, points68, *, mesh=None, params: SkinParams = SkinParams(),
                 crop: bool = True) -> FaceSegmentation:
    """Segment a face into skin, hair, brows, beard/stubble and specular highlights.

    The head region (:func:`head_region_mask`) minus the grown features is tested against
    the face's own skin colour (:func:`skin_colour_distance`, fitted to the face region):
    large off-colour or dark pieces are hair (or glasses, occluders), grown by
    ``occluder_margin``; skin-coloured hair is found as coherent strands
    (:func:`hair_strand_mask`); stubble and beard by dark-speck density
    (:func:`stubble_mask`) and the rough-and-dark test of :func:`beard_mask`; highlights
    (:func:`highlight_mask`) stay skin. Hand-written from landmarks, colour and texture
    (no face-parsing weights ship in a registry package usable here; see
    benchmarks/skin_segmentation.py for the IoU against hand-checked masks). ``crop``: work
    on the head region's box (the default; ``False``: on the whole image, the same labels)."""
    p = _p68(points68)
    img = _rgb01(image)
    h, w = img.shape[:2]
    fw = face_width(p)
    region = head_region_mask(p, (h, w), mesh=mesh, params=params)
    # work on the head region's box only (a fifth of a 1000 px portrait): every step is local
    # within 4 × its widest blur (0.03 × face width) or confined to the region, so the labels
    # are the same as on the whole image at a fraction of the time
    ys, xs = np.nonzero(region)
    pad = int(np.ceil(0.2 * fw)) + 2
    y0, y1 = max(0, ys.min() - pad), min(h, ys.max() + pad + 1)
    x0, x1 = max(0, xs.min() - pad), min(w, xs.max() + pad + 1)
    if crop and (y1 - y0) * (x1 - x0) < 0.8 * h * w:
        off = np.array([x0, y0], np.float64)
        sub_mesh = None if mesh is None else np.asarray(mesh, np.float64)[:, :2] - off
        seg = segment_face(img[y0:y1, x0:x1], p - off, mesh=sub_mesh, params=params, crop=False)
        return seg.padded((h, w), (y0, x0))
    face = face_region_mask(p, (h, w), mesh=mesh, shrink=params.oval_shrink)
    feats = feature_mask(p, (h, w), params)
    brows = np.zeros((h, w), np.uint8)
    for brow in _BROWS:
        _poly(brows, p[list(brow)], closed=False, thickness=int(round(params.brow_width * fw)))
    brows = _dilate(brows, params.brow_margin * fw) > 0
    chroma, light = skin_colour_distance(img, p, region=face & ~feats)
    ok = ((chroma < params.chroma_sigmas) | (light > params.highlight_sigmas)) & (light > -params.dark_sigmas)
    border = region & ~(cv2.erode(region.astype(np.uint8), disc(max(1, int(0.02 * fw)))) > 0)
    # bright pieces pass as highlights only inside the face: one reaching the
    # region's border is the background or grey hair beyond the hairline (on FRL 042, dark
    # skin, his short grey hair and the wall above it were all "highlight")
    bright = (ok & (light > params.highlight_sigmas) & region).astype(np.uint8)
    n, lab, _, _ = cv2.connectedComponentsWithStats(bright, connectivity=8)
    if n > 1:
        ok &= ~np.isin(lab, np.setdiff1d(np.unique(lab[border]), [0]))
    bad = (~ok & region).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(bad, connectivity=8)
    big = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] >= (params.occluder_min * fw) ** 2)
    # off-colour pieces: hair if they reach the region's border or rise above the brows
    # (hair comes from outside the face); background if grey (far less saturated than the
    # skin, not dark); otherwise shadows and dark circles round the features, skin unless
    # very dark or far off in colour
    mx = img.max(-1)
    sat = (mx - img.min(-1)) / (mx + 1e-3)
    s0 = float(np.median(sat[face & ~feats & ok])) if (face & ~feats & ok).any() else float(np.median(sat))
    brow_top = float(p[17:27, 1].min())
    grey = (cv2.GaussianBlur(sat, (0, 0), 0.005 * fw) < params.background_chroma * s0) & (light > -1.5)
    hair0 = np.zeros((h, w), bool)
    other = np.zeros((h, w), bool)
    for i in big[big > 0]:
        piece = (lab == i) & ~feats
        if not piece.any():
            continue
        if float(np.mean(grey[piece])) > 0.5:
            other |= piece
        elif (piece & border).any() or stats[i, cv2.CC_STAT_TOP] < brow_top:
            hair0 |= piece
        elif float(np.median(light[piece])) < -1.5 * params.dark_sigmas \
                or float(np.median(chroma[piece])) > 2 * params.chroma_sigmas:
            other |= piece
    ref = _reference_skin(p, (h, w)) & face & ~feats
    strands = hair_strand_mask(img, p, region, ref, params, exclude=feats)
    hair0 = (hair0 | strands) & ~grey
    other |= grey & ~ok
    # strand tips at the hairline and a fringe's edge: grown by a margin above the eyes only
    # (below, the off-colour pieces at the region's edge are the silhouette's shade, not hair)
    grown = _dilate(hair0.astype(np.uint8), params.occluder_margin * fw) > 0
    grown[int(np.clip(p[36:48, 1].mean(), 0, h)):] = False
    hair = (hair0 | grown) & region & ~feats & ~other
    ok = ok | ((lab > 0) & ~hair & ~other)  # the shadows kept as skin
    beard = np.zeros((h, w), bool)
    speckled = np.zeros((h, w), bool)
    if params.beard:
        # the rough-and-dark test away from the silhouette and the features' shadows
        inner = (cv2.erode(face.astype(np.uint8), disc(max(1, int(0.03 * fw)))) > 0) \
            & ~(_dilate(feats.astype(np.uint8), 0.025 * fw) > 0)
        bare = region & ok & ~hair & ~other & ~feats & (light < params.highlight_sigmas)  # a highlight rings no specks
        beard = (stubble_mask(img, p, bare, ref, params, exclude=feats)
                 | beard_mask(img, p, inner, light, params)) & ~hair & ~feats
        # sparser dark specks than a beard's (its fading edge, a shaved shadow): not a texture source
        dens, _ = dark_speck_density(img, fw, reference=ref, within=bare)
        ref_d = float(np.median(dens[ref])) if ref.any() else 0.0
        speckled = dens > max(0.5 * params.stubble_density, params.source_speck * ref_d)
        # speckled skin is hair where hair grows: above the brows when it touches the non-skin
        # beyond the hairline (short or grey hair at the hairline), and in the beard zone (a
        # thin moustache, a chin tuft, shaved stubble: the opening of stubble_mask drops them)
        dense = dens > max(params.stubble_density, params.source_speck * ref_d)  # as dense as stubble
        sp = cv2.morphologyEx((dense & bare).astype(np.uint8), cv2.MORPH_CLOSE, disc(max(1, int(0.01 * fw))))
        n, lab, stats, _ = cv2.connectedComponentsWithStats(sp, connectivity=8)
        if n > 1:
            beyond = _dilate((region & ~bare & ~feats & ~beard).astype(np.uint8), 0.01 * fw) > 0
            beyond[int(np.clip(brow_top, 0, h)):] = False
            hairline = np.setdiff1d(np.unique(lab[beyond & (sp > 0)]), [0])
            near = _dilate((region & ~bare & ~feats & ~beard).astype(np.uint8), 0.03 * fw) > 0  # a band, not the forehead
            hair |= np.isin(lab, hairline) & near & region & ~feats
            # (off the lip line and nostril rims and the jaw's silhouette: their shade specks too)
            zone = beard_zone_mask(p, (h, w), params) & inner & ~(_dilate(feats.astype(np.uint8), 0.008 * fw) > 0)
            tuft = cv2.morphologyEx(((sp > 0) & zone).astype(np.uint8), cv2.MORPH_OPEN, disc(1))
            n, lab, stats, _ = cv2.connectedComponentsWithStats(tuft, connectivity=8)
            big_t = [i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= (0.03 * fw) ** 2]
            beard |= np.isin(lab, big_t) & ~hair & ~feats

    skin = region & ok & ~hair & ~beard & ~feats
    skin = _fill_small_holes(skin, (params.hole_fill * fw) ** 2, light) & region & ~feats & ~hair & ~beard
    # keep the pieces connected to the reference skin and every large piece; drop islands
    n, lab, stats, _ = cv2.connectedComponentsWithStats(skin.astype(np.uint8), connectivity=8)
    if n > 2:
        seeds = set(np.unique(lab[(_sample_regions(p, (h, w)) | ref) & skin]).tolist())
        bigp = {i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= params.min_piece * fw * fw}
        skin = np.isin(lab, sorted((seeds | bigp) - {0}))
    hl = highlight_mask(img, skin, light, params, fw)
    labels = np.zeros((h, w), np.uint8)
    labels[feats] = LABELS["feature"]
    labels[brows & ~skin] = LABELS["brow"]
    labels[hair] = LABELS["hair"]
    labels[beard] = LABELS["beard"]
    labels[skin] = LABELS["skin"]
    labels[hl] = LABELS["highlight"]
    return FaceSegmentation(labels=labels, skin=skin, hair=hair & ~skin, brows=brows & feats, beard=beard,
                            highlight=hl, features=feats, region=region, speckled=speckled & skin,
                            beard_zone=beard_zone_mask(p, (h, w), params) if params.source_beard_zone else None)


def _feather_inwards(mask: np.ndarray, sigma: float) -> np.ndarray:
    """float32: ``mask`` eroded by 2σ and blurred (σ), zero outside ``mask``: soft inside,
    exactly 0 on everything the mask excludes."""
    if sigma <= 0.3:
        return mask.astype(np.float32)
    r = int(np.ceil(2 * sigma))
    core = cv2.erode(mask.astype(np.uint8), disc(r))
    out = cv2.GaussianBlur(core.astype(np.float32), (0, 0), sigma)
    return np.where(mask, np.clip(out, 0, 1), 0).astype(np.float32)


def skin_mask(image, points68, *, mesh=None, colour: bool = True, params: SkinParams = SkinParams(),
              soft: bool = True, return_parts: bool = False, source: bool = False):
    """Skin of the face: float32 (H, W) in [0, 1] (``soft``) or bool.

    The whole skin of :func:`segment_face` — up to the hairline, over the temples and to
    the jaw edge, without hair, beard, stubble and the grown features; highlights included
    (they are the content's own shading). ``source=True`` gives the skin a style may lend
    texture from: minus highlights and ``source_margin`` × face width away from hair and
    beard. Without ``colour`` only the geometry: the face region minus the features. The
    edge is feathered *inwards*, so the mask is exactly 0 on every feature and outside.
    ``return_parts`` adds a dict of the bool parts (region, colour, features, hair, beard,
    highlight, labels) for inspection.
    """
    p = _p68(points68)
    img = np.asarray(image)
    h, w = img.shape[:2]
    fw = face_width(p)
    if colour:
        seg = segment_face(img, p, mesh=mesh, params=params)
        skin = seg.source(params.source_margin, fw) if source else seg.skin
        parts = {"region": seg.region, "colour": ~(seg.hair | seg.beard), "features": seg.features,
                 "hair": seg.hair, "beard": seg.beard, "highlight": seg.highlight, "labels": seg.labels}
    else:
        region = head_region_mask(p, (h, w), mesh=mesh, params=params)
        feats = feature_mask(p, (h, w), params)
        skin = region & ~feats
        parts = {"region": region, "colour": np.ones((h, w), bool), "features": feats}
    out = _feather_inwards(skin, params.feather * fw) if soft else skin
    if return_parts:
        return out, parts
    return out
