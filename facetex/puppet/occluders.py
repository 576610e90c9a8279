"""What lies over a face in the composite (:mod:`facetex.puppet.composite`): the skin-coloured pixels
of a face (:func:`skin_pixels`), the pieces that are neither skin nor its features over the driver's
face (:func:`occlusion_mask`: a fringe, glasses, a hand) and the persona's own hair in its rendered
face (:func:`persona_hair`)."""

from __future__ import annotations

import cv2
import numpy as np

from ..geometry.masks import disc

__all__ = ["skin_pixels", "occlusion_mask", "persona_hair", "outline_band", "REACH"]

#: what lies over a face comes in over its outline: a piece reaches this close to it (x face width)
REACH = 0.03


def outline_band(region, points68, *, reach: float = REACH) -> np.ndarray:
    """bool (H, W): the pixels within ``reach`` x face width of the edge of the bool face
    ``region`` or outside it (the image's border counts as an edge)."""
    from ..geometry.masks import face_width

    r = max(1, int(round(reach * face_width(points68))))
    inner = cv2.erode(np.asarray(region, np.uint8), disc(r), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return inner == 0


def skin_pixels(image, points68, region, *, inside_features: bool = False) -> tuple[np.ndarray | None, np.ndarray]:
    """(bool (H, W) or None, bool (H, W)): the pixels of the bool ``region`` of ``image``
    (H, W, 3) sRGB outside the grown eyes, brows, lips and nostrils that have the face's own skin
    colour (chromaticity and lightness, :func:`facetex.geometry.skin.skin_colour_distance`, fitted
    robustly to that region: hair, stubble, shadows and glasses frames fall out), and those
    features (:func:`facetex.geometry.skin.feature_mask`). None when fewer than 20 pixels are left
    to fit the colour. ``inside_features``: the skin-coloured pixels of all of ``region``, the
    features' grown masks included (the colour still fitted outside them)."""
    from ..geometry.skin import SkinParams, skin_colour_distance
    from ..geometry.skin import feature_mask as grown_features

    sp = SkinParams()
    feats = grown_features(points68, region.shape, sp)
    base = region & ~feats
    if base.sum() < 20:
        return None, feats
    chroma, z = skin_colour_distance(image, points68, region=base)
    return (region if inside_features else base) & (chroma < sp.chroma_sigmas) & (z > -sp.dark_sigmas), feats


def occlusion_mask(region, skin, features, points68, *, min_size: float = 0.03, apart: float = 0.06,
                   margin: float = 0.02, soft: float = 0.01, counted=None, touching=None) -> np.ndarray:
    """float32 (H, W) in [0, 1]: what lies over the driver's face (a fringe, glasses, a hand of
    another colour): pixels of the bool ``region`` (the face outline) that are neither ``skin``
    nor ``features`` (the bool pair of :func:`skin_pixels` on the driver's frame: its eyes, brows,
    lips and nostrils are replaced by the puppet's). A piece counts when more than (``min_size``
    x face width)² of it lies further than ``apart`` x face width from the features (a mole or a
    crease's shadow is smaller; the brow hairs and nostril shadows beyond the landmark polygons
    lie next to them; ``counted``: other features for that distance, default ``features``) and,
    with a bool ``touching`` (H, W), has a pixel there; it is grown by ``margin`` x face width
    (strand tips, frame edges) and softened by a Gaussian of ``soft`` x face width."""
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
    near = cv2.dilate((features if counted is None else counted).view(np.uint8), disc(r)) > 0
    away = np.bincount(lab[~near], minlength=n)  # each piece's pixels away from the features
    keep = away >= (min_size * fw) ** 2
    if touching is not None:
        keep &= np.bincount(lab[np.asarray(touching, bool)], minlength=n) > 0
    big = np.flatnonzero(keep[1:]) + 1
    if not len(big):
        return out
    occ = np.isin(lab, big).astype(np.uint8)
    r = int(round(margin * fw))
    if r >= 1:
        occ = cv2.dilate(occ, disc(r))
    occ = occ.astype(np.float32)
    if soft * fw > 0.3:  # 1 up to the grown edge, falling to 0 over ~2 sigma outside it
        occ = np.minimum(2 * cv2.GaussianBlur(occ, (0, 0), soft * fw), 1.0)
    return occ * region


def persona_hair(image, points68, region, *, area=None) -> np.ndarray:
    """float32 (H, W) in [0, 1]: the persona's own hair in its rendered face ``image`` (H, W, 3)
    with its landmarks ``points68``: :func:`occlusion_mask` of the puppet's :func:`skin_pixels` in
    the bool ``region`` above its lower lids (a fringe or hair over the temples in most of a
    collection's photos is in its average texture; drawn into the driver's frame it took the
    driver's skin colour as orange and blue smears round the brows; a beard below is the persona's).
    ``area`` (bool, e.g. the rendered face's coverage): where pieces of hair are followed beyond
    ``region`` (the mask stays inside it). Inside the brows' grown masks the pieces are cut along the
    brows' own band (no margin): a strand over a temple that runs into a brow's tail (Arroyo's
    photos) showed as a dark streak there, while the brows' edges, within their grown masks, never
    count as a piece on their own (its size is counted outside the grown masks). A piece is hair only
    where it reaches the face's outline (:func:`outline_band` of ``region``, or beyond it in
    ``area``): hair grows in from the scalp, while a dark-skinned persona's shaded
    upper lids and brow heads (Williams, Blair, Arroyo: a blob over each inner lid, apart from
    the outline) are the face's own, and taken for hair they showed the driver's skin there, a
    pale patch over each lid under the colour of ``colour="persona"`` and a brow raised at its head
    under the driver's."""
    import dataclasses

    from ..geometry.skin import SkinParams
    from ..geometry.skin import feature_mask as grown_features

    p = np.asarray(points68, np.float64)
    search = region if area is None else (region | np.asarray(area, bool))
    upper = np.zeros(np.shape(region), bool)
    upper[:max(0, int(np.ceil(np.nanmax(p[36:48, 1]))))] = True
    skin, feats = skin_pixels(image, p, search, inside_features=True)
    if skin is None:
        return np.zeros(np.shape(region), np.float32)
    tight = grown_features(p, np.shape(region), dataclasses.replace(SkinParams(), brow_margin=0.0))
    edge = outline_band(region, p)
    # next to the features too (apart 0): hair at the temples meets the brows' grown masks
    return occlusion_mask(search & upper, skin, tight, p, apart=0.0, counted=feats, touching=edge) * region
