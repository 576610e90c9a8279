"""The puppet's eyes in the composite (:mod:`facetex.puppet.composite`): the driver's own whites,
lash line and gaze drawn inside the puppet's lids, as the mouth's interior is drawn inside its lips
(:mod:`facetex.puppet.mouth`), with the persona's iris colour; and the weights with which the
persona's own eyes and lids keep or take colour in the skin colour transfer."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import BadInputError
from ..geometry.masks import disc, polygon_mask
from ..geometry.skin import _sample_regions, brow_mask
from ._contours import EDGE_MAX_PX, EYE, _contour_frame, _open_fade, sample_between
from ._pixels import _LUMA, _shape2
from .lighting import _lab, _linear, _rgb

__all__ = ["persona_iris", "iris_shift", "eye_interior", "eye_weights", "lid_weights", "brow_weights",
           "eye_skin_weights"]

#: iBUG-68 eye contours (outer or inner corner, upper lid, other corner, lower lid)
EYES = ((36, 37, 38, 39, 40, 41), (42, 43, 44, 45, 46, 47))


def _dark_median(lab: np.ndarray, dark: float) -> np.ndarray:
    """Median CIELAB (3,) of the darkest ``dark`` % of the pixels ``lab`` (N, 3)."""
    return np.median(lab[lab[:, 0] <= np.percentile(lab[:, 0], dark)], axis=0)


def _eye_middles(points68: np.ndarray, shape, middle: float = 0.4) -> np.ndarray:
    """bool (H, W): both eye contours' pixels at least ``middle`` x their deepest pixel's distance
    from the contour (away from the lids' margins and the corners)."""
    out = np.zeros(shape, bool)
    for idx in EYES:
        m = (polygon_mask(points68[list(idx)], shape) > 0.5).astype(np.uint8)
        if m.any():
            d = cv2.distanceTransform(m, cv2.DIST_L2, 3)
            out |= d >= middle * d.max()
    return out


def persona_iris(images, points68, *, dark: float = 40.0, middle: float = 0.4, photos: int = 64) -> np.ndarray | None:
    """Linear-light RGB ratio (3,) of a persona's iris to its skin, or None: for each of up to
    ``photos`` evenly spaced photos (``images`` (n, H, W, 3) uint8 sRGB or a function of the photo's
    index that returns its image, e.g. :meth:`facetex.persona.Persona.image`; ``points68``
    (n, 68, 2) in them), the median of the darkest ``dark`` % of both eyes' middles (:func:`_eye_middles`) over
    the median of its cheeks and nose bridge, per channel; the median over the photos. A ratio of
    reflectances: times the driver's skin it is the iris under the frame's light. From the photos,
    not the rendered puppet: at a video's size the rendered eye is a few blurred pixels whose dark
    part is the lids' red-brown (it turned a brown iris maroon)."""
    n = len(points68)
    image = images if callable(images) else images.__getitem__
    ratios = []
    for i in np.unique(np.linspace(0, n - 1, min(n, photos)).round().astype(int)):
        p = np.asarray(points68[i], np.float64)
        if not np.isfinite(p).all():
            continue
        img = np.asarray(image(i), np.float32) / 255.0
        eyes, skin = _eye_middles(p, img.shape[:2]), _sample_regions(p, img.shape[:2])
        if eyes.sum() < 4 or skin.sum() < 16:
            continue
        lin = _linear(img)
        y = lin[eyes] @ _LUMA
        iris = np.median(lin[eyes][y <= np.percentile(y, dark)], axis=0)
        ratios.append(iris / np.maximum(np.median(lin[skin], axis=0), 1e-4))
    return np.median(ratios, axis=0).astype(np.float32) if ratios else None


def iris_shift(driver_eye: np.ndarray, target: np.ndarray, *, dark: float = 40.0, light: float = 90.0,
               max_lightness: float = 10.0) -> tuple[np.ndarray, float, float]:
    """(CIELAB shift (3,), L*_light, L*_dark) that gives the driver's iris the colour ``target``
    (3,) linear-light RGB: from the median colour of the driver's eye's darkest ``dark`` %
    (``driver_eye`` (N, 3) CIELAB: iris, pupil and lash line) to the target's, the target scaled to
    within ``max_lightness`` L* of it (a persona's eye measured in small photos holds pupil and
    lashes too); the eye's L* at its ``light`` percentile (the whites) and its dark part's median.
    A pixel takes the shift in full at the dark part's lightness, none at the whites'."""
    d = _dark_median(driver_eye, dark)
    t = np.maximum(np.asarray(target, np.float32), 1e-6)
    lt = float(cv2.cvtColor(t[None, None], cv2.COLOR_LRGB2Lab)[0, 0, 0])
    want = d[0] + np.clip(lt - d[0], -max_lightness, max_lightness)
    t = t * _lightness_to_y(want) / max(_lightness_to_y(lt), 1e-9)
    shift = cv2.cvtColor(t[None, None].astype(np.float32), cv2.COLOR_LRGB2Lab)[0, 0].astype(np.float64) - d
    return shift, float(np.percentile(driver_eye[:, 0], light)), float(d[0])


def _lightness_to_y(L: float) -> float:
    """CIE luminance Y (white 1) of lightness L* (the inverse of CIELAB's L*)."""
    f = (L + 16.0) / 116.0
    return f ** 3 if f > 6 / 29 else 3 * (6 / 29) ** 2 * (f - 4 / 29)


def eye_interior(frame, driver68, puppet68, shape=None, *, iris=None, inset: float = 1.0, soft: float = 0.3,
                 closed: float = 0.08, soft_px: float | None = EDGE_MAX_PX) -> tuple[np.ndarray, np.ndarray]:
    """The driver's eyeballs moved into the puppet's eyes: (image (H, W, 3), alpha (H, W)).

    ``driver68`` (68, 2) the driver's iBUG landmarks in ``frame`` px, ``puppet68`` the puppet's in
    output px (``shape``, default the frame's). Inside each of the puppet's eye contours (the lids'
    edges) every pixel takes the driver's pixel at the same place between the eye's corners and
    between its lids (:func:`~facetex.puppet._contours.sample_between`, pulled towards the centre by
    ``inset``): the driver's whites, lash line and gaze in the puppet's lids, at the puppet's
    opening. Alpha rises from 0 at the contour to 1 over ``soft`` x the eye's widest opening (at
    most ``soft_px`` pixels, :meth:`~facetex.puppet._contours.Between.edge`), faded
    out as the driver's opening falls from 2 x ``closed`` to ``closed`` times its eye width (a
    closing eye shows the puppet's own lids). ``iris`` (3,) linear-light RGB: the colour the
    driver's iris takes (:func:`iris_shift`; the whites keep the driver's), e.g. the driver's skin
    times :func:`persona_iris`: a brown-eyed persona must not look out of a green-eyed driver's eyes.
    Why: the puppet's eyes come from its texture, made in the persona's neutral frame and stretched
    open by the lids' motion; a dark persona's eyes rendered as dark almonds without whites (dlib
    read them 0.78-0.85 as open as their mesh)."""
    f = np.asarray(frame, np.float32)
    h, w = _shape2(f.shape if shape is None else shape)
    dp, pp = np.asarray(driver68, np.float64), np.asarray(puppet68, np.float64)
    if dp.shape != (68, 2) or pp.shape != (68, 2):
        raise BadInputError(f"eye interior needs (68, 2) landmarks, got {dp.shape} and {pp.shape}")
    img, alpha = np.zeros((h, w, 3), np.float32), np.zeros((h, w), np.float32)
    for idx in EYES:
        d, p = dp[list(idx)], pp[list(idx)]
        if not (np.isfinite(d).all() and np.isfinite(p).all()):
            continue
        _, _, wd, gd = _contour_frame(d, EYE)
        fade = _open_fade(wd, gd, closed)
        if fade <= 0:
            continue
        s = sample_between(f, d, p, (h, w), layout=EYE, inset=inset)
        if s is None:
            continue
        x0, y0, x1, y1 = s.box
        a = s.edge(soft, max_px=soft_px) * fade
        warped = s.warped
        inside = a > 0.5 * a.max()
        if iris is not None and inside.sum() >= 8:
            lab = _lab(warped)
            shift, light, dark = iris_shift(lab[inside], iris)
            t = np.clip((light - lab[..., 0]) / max(light - dark, 1e-3), 0.0, 1.0)[..., None]
            warped = _rgb(lab + t * shift.astype(np.float32))
        sub = alpha[y0:y1, x0:x1]
        take = a > sub  # the two eyes' boxes can touch at a small size: the stronger alpha wins
        img[y0:y1, x0:x1][take] = warped[take]
        sub[take] = a[take]
    return img, alpha


# ----------------------------------------------------------------------------- the persona's own eyes
def _eyeballs(p: np.ndarray, shape) -> np.ndarray:
    """bool (H, W): inside either eye outline (36-41, 42-47) of iBUG landmarks ``p``."""
    return np.maximum(polygon_mask(p[36:42], shape), polygon_mask(p[42:48], shape)) > 0.5


def lid_weights(points68, shape, *, margin: float = 0.045, feather: float = 0.015) -> tuple[np.ndarray, np.ndarray]:
    """(weight (H, W) float32, bool (H, W)) of the lids round both eyes at iBUG landmarks
    ``points68``: the eye outlines (36-41, 42-47) grown by ``margin`` x the face width (the
    margin :func:`facetex.geometry.skin.feature_mask` leaves out of the skin) minus the eyeballs,
    feathered by ``feather`` x the eye-corner distance, and the ring's pixels (a pixel in from
    both edges) where its colour is measured (:func:`~facetex.puppet.lighting.transfer_skin_colour`)."""
    from ..geometry.masks import face_width

    p = np.asarray(points68, np.float64)
    h, w = _shape2(shape)
    balls = _eyeballs(p, (h, w))
    r = max(1, int(round(margin * face_width(p))))
    grown = cv2.dilate(balls.astype(np.uint8), disc(r)) > 0
    ring = grown & ~balls
    inner = cv2.erode(ring.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    sig = max(0.75, feather * float(np.linalg.norm(p[36] - p[45])))
    return np.clip(cv2.GaussianBlur(grown.astype(np.float32), (0, 0), sig), 0, 1), inner


def eye_skin_weights(points68, shape, *, other68=None, below: float = 0.25, beyond: float = 0.25,
                     feather: float = 0.05, lashes: float = 0.06) -> tuple[np.ndarray, np.ndarray]:
    """(weight (H, W) float32 in [0, 1], bool (H, W)) of the skin under both eyes at iBUG landmarks
    ``points68``: each lower lid's outline, its outer corner moved out by ``beyond`` x the eye-corner
    distance, and the band between it and the same moved down by ``below`` x that distance,
    feathered by ``feather`` x that distance (Gaussian sigma, x 1.5 and clipped: 1 inside); and the
    eyeballs grown by ``lashes`` x that distance (the lash lines and the lids' rims), which are not
    skin, those of ``other68`` (another face's landmarks in the same image, or None) as well."""
    p = np.asarray(points68, np.float64)
    h, w = _shape2(shape)
    iod = float(np.linalg.norm(p[36] - p[45]))
    zone = np.zeros((h, w), np.float32)
    for lower in ([36, 41, 40, 39], [45, 46, 47, 42]):  # from the outer corner in
        q = p[lower].copy()
        q[0, 0] += beyond * iod * np.sign(q[0, 0] - q[-1, 0])
        zone = np.maximum(zone, polygon_mask(np.concatenate([q, (q + [0.0, below * iod])[::-1]]), (h, w)))
    weight = np.clip(1.5 * cv2.GaussianBlur(zone, (0, 0), max(0.75, feather * iod)), 0, 1)
    eyes = np.zeros((h, w), bool)
    for q in (p,) if other68 is None else (p, np.asarray(other68, np.float64)):
        r = max(1, int(round(lashes * float(np.linalg.norm(q[36] - q[45])))))
        eyes |= cv2.dilate(_eyeballs(q, (h, w)).astype(np.uint8), disc(r)) > 0
    return weight, eyes


def brow_weights(points68, shape, *, feather: float = 0.03) -> np.ndarray:
    """Weight (H, W) float32 in [0, 1] of both brows at iBUG landmarks ``points68``: the brows of
    :func:`facetex.geometry.skin.brow_mask` (as the skin model leaves them out), feathered by
    ``feather`` x the eye-corner distance."""
    p = np.asarray(points68, np.float64)
    sig = max(0.5, feather * float(np.linalg.norm(p[36] - p[45])))
    return np.clip(cv2.GaussianBlur(brow_mask(p, shape).astype(np.float32), (0, 0), sig), 0, 1)


def eye_weights(points68, shape, *, feather: float = 0.015, grow: float = 0.0, spread: float = 0.0,
                inset: float = 0.0) -> np.ndarray:
    """Weight (H, W) float32 in [0, 1] of the eyeballs at iBUG landmarks ``points68``: both eye
    outlines (36-41, 42-47, the lids' edges), grown by ``grow`` x the eye-corner distance, then
    feathered by ``feather`` x that distance (Gaussian sigma) inwards: the lids' skin beyond them
    is not counted; ``spread`` > 0: then blurred by ``spread`` x that distance both ways (no edge
    where a weight ends on skin); ``inset`` > 0: the feather starts this x that distance inside the
    outlines (0 on them)."""
    p = np.asarray(points68, np.float64)
    h, w = _shape2(shape)
    m = np.maximum(polygon_mask(p[36:42], (h, w)), polygon_mask(p[42:48], (h, w)))
    iod = float(np.linalg.norm(p[36] - p[45]))
    if grow > 0:
        r = max(1, int(round(grow * iod)))
        m = cv2.dilate((m > 0.5).astype(np.uint8), disc(r)).astype(np.float32)
    sig = max(0.5, feather * iod)
    inner = cv2.erode((m > 0.5).astype(np.uint8), np.ones((3, 3), np.uint8))
    if inset > 0:
        inner = cv2.erode(inner, disc(max(1, int(round(inset * iod)))))
    inner = inner.astype(np.float32)
    w = np.clip(cv2.GaussianBlur(inner, (0, 0), sig), 0, 1) * (m > 0.5)
    return cv2.GaussianBlur(w, (0, 0), max(0.5, spread * iod)) if spread > 0 else w
