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
  (:func:`~facetex.puppet.lighting.transfer_skin_colour`). One mean shift over the whole face (Reinhard et al. 2001, still
  :func:`~facetex.puppet.lighting.match_color_statistics`) kept a dark persona's own shading at its full depth on a pale
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
  variance, on the 44-71-photo personas); where that bound leaves it smoother than the frame (a
  frame at its own size, finer than the persona's photos), the frame's own grain is added on the
  skin (:func:`~facetex.puppet.detail.match_grain`), on a large frame in the octaves between the
  pixel and the persona's resolution too (:func:`~facetex.puppet.detail.match_grain_bands`); the
  lower nose gets its own gain, matched to the driver's nose (its nostrils and shaded sides are not
  skin-coloured, so the skin's gain never saw them);
* **gradient-domain blending** (optional, ``poisson``): the puppet's gradients with the driver's
  values on the mask border (Pérez et al. 2003; ``seamlessClone``'s guidance field solved in float32
  by the DST). Off by default: after the skin-colour transfer its membrane only carried the
  driver's hair, ears and jaw shadow at the outline into the face, a darker, greyer cast (see
  :class:`CompositeParams`);
* **mouth interior**: the driver's own mouth interior (teeth, tongue, dark cavity), each
  puppet pixel taking the driver's pixel at the same place between the mouth corners and
  between the upper and lower inner lip (smooth curves through the landmarks), drawn inside the
  puppet's inner lips with a soft edge while the driver's lips are apart, the driver's lip
  colour keyed out.
* **eyes**: the driver's eyeballs (whites, lash line, gaze) drawn the same way inside the
  puppet's lids while the driver's eyes are open, its iris in the persona's colour
  (:mod:`~facetex.puppet.eyes`).

Plus the measure of the result: :func:`boundary_color_step` (ΔE between bands just inside and
just outside the mask edge).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import BadInputError
from ..geometry.masks import disc, feature_mask, inner_feather, nose_mask, polygon_mask
from ._pixels import _LUMA, _mix, _Shrunk, _skin_weights
from ._poisson import poisson_blend
from .detail import (GRAIN_FILL_STEP, brow_bands, feature_parts, grain_fill, match_grain, match_grain_bands,
                     match_lid_detail, match_lip_detail, match_sharpness)
from .lighting import (COLOURS, _lab, _linear, fit_sh_lighting, floor_nostrils, linear_to_srgb, relight,
                       srgb_to_linear, transfer_skin_colour)
from .eyes import _eyeballs, brow_weights, eye_interior, eye_skin_weights, eye_weights, lid_weights
from .mouth import lift_inner_lips, lip_regions, lip_weights, mouth_interior  # noqa: F401 (lip_weights re-exported)
from .occluders import occlusion_mask, outline_band, persona_hair, skin_pixels

__all__ = [
    "FACE_OVAL",
    "INNER_LIPS",
    "lip_weights",
    "lip_regions",
    "lid_weights",
    "eye_weights",
    "skin_pixels",
    "occlusion_mask",
    "persona_hair",
    "poisson_blend",
    "boundary_color_step",
    "CompositeParams",
    "composite_face",
]

#: MediaPipe 468-mesh vertices on the face outline (forehead top, temples, jaw, chin), in order.
FACE_OVAL = (10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377, 152,
             148, 176, 149, 150, 136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109)
#: iBUG-68 inner-lip contour, in order (left corner, upper lip, right corner, lower lip).
INNER_LIPS = (60, 61, 62, 63, 64, 65, 66, 67)


def _scaled(weights: tuple, strength: float) -> tuple:
    """(weight x ``strength``, pixels): a region weight of :func:`~facetex.puppet.lighting.transfer_skin_colour` in part."""
    return np.asarray(weights[0], np.float32) * float(np.clip(strength, 0.0, 1.0)), weights[1]


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
#: the persona's own hair in its rendered face is found at about this many px between the eye corners
HAIR_IOD = 40.0
#: the lids' rims (``keep_dark`` of :func:`~facetex.puppet.lighting.transfer_skin_colour`) fade out
#: over this x the eye-corner distance (Gaussian sigma) both ways: cut at the grown outline, their
#: edge drew a polygon round a dark persona's eyes on a pale driver at 1080 px
EYE_RIM_SPREAD = 0.02
#: with the driver's eyeballs drawn in, the puppet's own keep their lightness only from this x the
#: eye-corner distance inside its lids' edges: kept up to them, its grey eyeball's edge showed as a
#: light outline round the inserted eyes (whose alpha rises from 0 there) on a dark 1000 px driver
EYE_KEEP_INSET = 0.03
#: where the puppet's eyeballs come from: the driver's frame (with the persona's iris colour) or
#: the persona's texture
EYE_SOURCES = ("driver", "persona")
#: the feather (Gaussian sigma, x the eye-corner distance) of the brows' own highlight knee
BROW_KNEE_FEATHER = 0.03
#: the lips' polygons grown by this and feathered by that (Gaussian sigma), x the eye-corner
#: distance: where ``CompositeParams.mouth_colour_sigma`` sets the colour field's scale
MOUTH_FIELD_GROW, MOUTH_FIELD_FEATHER = 0.15, 0.05
#: the inward feather is this many times wider with ``colour="persona"`` (the persona's own tone
#: meets the driver's at the outline)
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
    lightness-detail gain (:func:`~facetex.puppet.lighting.transfer_skin_colour`): at 0.06 the
    persona's shading above ~0.1 eye distances (eye sockets, the nose's sides, the cheek folds) was
    the driver's, and dlib read the composites nearer the driver (``bench puppet`` portraits: 6 of 42
    runs under 80 % of frames nearer the persona's photos, Koizumi on FRL 096 0 %; at 0.15 one run,
    Koizumi on FRL 096, 50 %; cheek ΔE to the driver worst 1.9 -> 5.5 and 2.6 -> 5.8 on 60 GRID
    runs, within the bruise bound of 8; at 0.25 7.9). A gain of at least 1 (a pale persona's features
    at full contrast on a dark driver) read nearer still, but dlib then read Koizumi's puppet's mouth
    opening at 0.70-0.76 of a dim or dark-skinned GRID driver's (0.92-0.96 before);
    mouth_colour_sigma: round both faces' lips (grown by ``MOUTH_FIELD_GROW``, feathered by
    ``MOUTH_FIELD_FEATHER`` eye-corner distances) the colour field's scale is this instead (None:
    colour_sigma there too): with the persona's own shading round its mouth dlib read Koizumi's
    puppet's opening at 0.84-0.85 of two GRID drivers' (0.92-0.93 at 0.06 everywhere; with this 0.87-0.90,
    his identity on FRL 096 unchanged; grown by 0.3 it was 0.89-0.90 but read nearer that driver); chroma_gain: the
    bounds of the a*, b* detail's gain, the skins' chroma ratio, and highlight_knee: lightness detail
    above the persona's skin compressed to this (L*) x tanh (both there): on 1000 px studio drivers
    (FRL London) a dark persona's brow ridges were white bands and her lash lines blue-black, an East
    Asian persona's brows teal, on pale drivers; brow_highlight_knee: this knee instead where either
    face's brows are (:func:`~facetex.puppet.detail.brow_bands`, feathered by ``BROW_KNEE_FEATHER``;
    None: off): a persona's brow ridge lit by her photos' flash lies where a driver's thicker brows
    were, and at 6 it was a pale arch over Williams' eyes on a stubbled pale 1000 px driver (FRL
    022); at 2 everywhere the persona's own highlights went too (its nose flattened, and FRL 096's
    composites read nearer that driver: 4 more frames in 10 on Arroyo); shadow_knee: the same for
    lightness detail below it on the skin (eyes, brows, lips and the lower nose left out; None: off),
    on a darker persona than the driver: her under-eye circles and cheek shading were black eyes and bruises on a pale
    driver (FRL 002); eye_skin: on such a pair the skin under the eyes
    (:func:`~facetex.puppet.eyes.eye_skin_weights`) takes the driver's colour down to this x the
    eye-corner distance (Gaussian sigma; 0: off; ``eye_skin`` of
    :func:`~facetex.puppet.lighting.transfer_skin_colour`): the skin masks leave a margin round the
    eyes out, so there both fields were the cheeks', and Williams' under-eye circles stayed a
    grey-brown band across pale 1000 px drivers' eyes (``bench puppet`` under-eye ΔL* -10 on FRL
    018, 0.0 now; at 0.05 -2.4); with the upper lids up to the brows as well her puppet read closer
    to her photos than to GRID lbax4n's speaker on 60 % of frames (100 % without them);
    lip_colour: with colour "driver" the lips take the driver's lips' colour (:func:`lip_weights`),
    not the skin's; eye_colour: the eyeballs keep the persona's lightness (:func:`eye_weights`;
    their a*, b* take the frame's white balance); eye_grow: out to this x the eye-corner distance
    beyond the lids' edges (their inward feather had mapped a dark persona's eye rims to a pale
    driver's skin: dlib read
    Williams' eyes on GRID lrwp9a at 360 px 0.77 as open as the driver's, 0.85 with 0.04 and the
    frame's white balance; ``bench puppet`` at 256 px: mean eye ratio 0.984 -> 0.999, share of
    frames at dlib distance < 0.6 worst 0.44 -> 0.56; kept whole, a pale persona's grown eyeballs
    were blue-grey patches in GRID lbax4n's orange frame). Beyond the lids' edges only a darker
    lightness is kept (``keep_dark`` of :func:`~facetex.puppet.lighting.transfer_skin_colour`): kept
    as it was, a pale persona's lid rims and the whites below its irises stayed pale on a dark
    driver, as white rings and crescents round the eyes (Koizumi's and Bush's personas on GRID clips
    with the skin darkened); on a darker persona than the driver the rims' dark detail takes the
    skins' lightness ratio instead (kept as it was, Williams' whole lids were dark maroon almonds
    round a pale driver's eyes at 1080 px; ``bench puppet`` eye ratio min 0.845 -> 0.835); both
    where the puppet draws its eyes (at the driver's landmarks a pale persona's lid skin was kept as
    white crescents under a dark 1000 px driver's eyes). Chosen by the cheek ΔE (CIELAB) to the
    driver's own cheeks over 6 personas x 6 GRID clips (worst run, skin-only masks: mean shift 19,
    MKL 22 (and pink lips), per-channel histogram matching 27, smooth field at 0.4 / 0.25 / 0.15 /
    0.10 / 0.08 eye distances 19 / 16 / 12 / 7.8 / 6.2; 0.12 to 0.08 look alike at 100 %; with the
    sharper eye and mouth textures 0.08 gave 9.1 on a dark persona over a pale driver, 0.06 7.2,
    alike at 100 %) and by looking at the eyes: a gain from the skins' high-pass spreads (0.5 on
    a dark persona over a pale driver) greyed the irises; an upper bound of 1.5 (a dark persona's
    skin is ~1.8x darker in L* than a pale driver's) blackened the eye sockets and nostrils and
    turned the lips white, 1.2 keeps them a face's (cheek ΔE 7.4 -> 6.7 on that pair);
    lip_ceiling: the lips' lightness is at most the driver's lip median + this (L*, None: off;
    :func:`~facetex.puppet.lighting.transfer_skin_colour`): with the lips' colour where the puppet's
    lips are (:func:`lip_regions`), teeth of a smiling persona's texture at its inner lips still
    drew a light line along the opening (the lips' highlights are scaled to it, not clipped);
    brow_gain: in the brows (:func:`~facetex.puppet.eyes.brow_weights`) the lightness detail
    darker than the persona's skin takes the skins' lightness ratio up to this (0: off; ``brows``
    of :func:`~facetex.puppet.lighting.transfer_skin_colour`): with the 1.2 bound Williams' brows on
    the pale GRID sbwe5n speaker were nearly gone (brow-to-forehead contrast 4.9-8.7 L* against the
    driver's own 8-10), 7.2-12 with 2 (an absolute keep of her brows' lightness, as for the lid rims,
    drew blocky dark-brown patches);
    lid_colour: the lids round the eyes take the driver's lid lightness at this strength
    (:func:`lid_weights`, 0: off, the default): a dark persona's dark lids looked like shadow rings
    on pale drivers, and at 1 Williams' eye openness rose (0.83-0.90 -> 0.84-0.95 of the driver's)
    and Bush/sbwe5n's mouth slope came into range (1.32 -> 1.20), but Chavez's deep-set eyes read
    less open (pwij3p 0.83 -> 0.79, at 0.5 0.80) and Koizumi/id2 came out 80 % closer to the
    persona (100 %); occlusion: keep the driver's occluders in front (:func:`occlusion_mask`, the
    pieces that reach its face's outline: a fringe, a hand; a pale-skinned driver's nose highlight,
    apart from it, showed as a pink patch on a dark persona's nose; its glasses' rims when
    ``composite_face`` is given them); persona_hair: the driver's frame shows where the
    persona's own hair lies over its forehead or temples (:func:`persona_hair`); sharpen: the
    puppet's fine detail is raised towards the driver's frame's, at most by this gain (1: off;
    :func:`match_sharpness`), on its skin (feathered by ``sharpen_feather`` x the eye-corner
    distance) and on its features (eyes, brows, lips, nostrils) by a gain of their own, measured
    against the driver's features (0: the skin's gain on the whole face, as before: on a small,
    compressed GRID face it drew the puppet's eyes, brows and lips harder than the video's own, the
    eyes up to 4.8x the driver's Laplacian variance); grain: then the frame's own grain is added
    where the puppet is still smoother, at most at this strength (0: off;
    :func:`~facetex.puppet.detail.match_grain`);
    grain_reach: before it, the frame's octave bands up to this x the eye-corner distance (sigma)
    are added where the puppet is smoother (:func:`~facetex.puppet.detail.match_grain_bands`; 0:
    the pixel band only): with the pixel band alone the puppets on 1000 px FRL drivers measured
    0.65-1.04 of the driver's face sharpness at full size and 0.17-0.39 at half size (36 runs of
    ``bench puppet --portraits 6``), with 0.015 0.71-1.28 and 0.37-0.86; grain_brows: both bands take
    the skin's grain where either face's brows are too (:func:`~facetex.puppet.detail.brow_bands`):
    left out, the driver's brows were a smooth arch over a persona with thinner brows;
    nose_sharpen: then the puppet's lower nose (:func:`~facetex.geometry.masks.nose_mask`) is raised
    to the driver's nose's fine detail, at most by this further gain (1: off): half of a GRID frame's
    Laplacian energy inside the face is its nose (nostrils, the shaded sides), which the skin-colour
    mask of the skin's gain leaves out, and the persona's nose, a blend of many photos, is soft (at
    the driver's 360 px, face sharpness 0.67-0.73 of the driver's on 4 of 36 runs without it, the
    nose 0.41-0.47); nostril_knee: then the puppet's lower nose is no darker than the driver's
    nostrils but for a soft knee of this many L* (0: off; :func:`~facetex.puppet.lighting.floor_nostrils`);
    lip_detail: the driver's lip lines moved onto the puppet's lips, at most at this
    strength (0: off; :func:`~facetex.puppet.detail.match_lip_detail`); lid_detail: the driver's lash
    lines and lid creases round the puppet's eyes, at most at this strength (0: off;
    :func:`~facetex.puppet.detail.match_lid_detail`); poisson: gradient-domain blending at the
    border (:func:`poisson_blend`; colour "driver" only). Off: the skin-colour transfer already gives
    the puppet the driver's low-frequency colour, and the membrane interpolated the outline's
    difference (the driver's hair, ears, jaw shadow and background there) across the whole face: a
    darker, greyer, ashy face (``bench puppet``, 36 portrait runs at 1000 px: cheek ΔE to the driver
    mean 3.1 / worst 5.6 with it, 0.85 / 1.95 without; under-eye ΔL* worst -8.6 / -3.9; 60 GRID and
    stress runs at 256 px: 2.9 / 5.6 -> 1.1 / 2.6); the inward feather alone joins the two (the
    colour step across the outline over the driver's own there: GRID 0.84-1.09, 0.90-1.08 with it;
    portraits 0.87-1.41, 0.60-1.11, no edge seen at 100 %); feather: width of the inward feather as
    a fraction of the eye-corner distance;
    erode: the driver's outline is shrunk by this fraction (the face-oval vertices sit on the
    silhouette, where skin meets hair or background); mouth: draw the driver's mouth interior
    inside the puppet's lips; lip_band: an open mouth's inner lip band (this x the mouth width) is
    lifted to the driver's band lightness, relative to each face's own lips when the puppet keeps
    its colour (colour "persona" or lighting "none") (0: off; :func:`~facetex.puppet.mouth.lift_inner_lips`;
    0.2: a thin-lipped persona's dark upper lip is most of a 0.1 band's width beyond it, and dlib read
    it as part of the opening: ``bench puppet`` at 256 px, 42 runs with the dark-skinned copy, widest
    mouth slope 1.313 -> 1.225 (Bush/bbaf2n), worst r 0.915 -> 0.936, narrowest 0.929 -> 0.912; at 360
    px 0.881-1.110 -> 0.876-1.107, r 0.921 -> 0.935);
    eyes: "driver" (default): the driver's eyeballs (whites, lash line, gaze) drawn inside the
    puppet's lids with the persona's iris colour (:func:`~facetex.puppet.eyes.eye_interior`);
    "persona": the eyes of the persona's texture only.
    """

    lighting: str = "stats"
    sh_strength: float = 1.0
    normal_smoothing: float = 0.05
    colour: str = "driver"
    colour_sigma: float = 0.15
    mouth_colour_sigma: float | None = 0.06
    colour_gain: tuple[float, float] = (2 / 3, 1.2)
    chroma_gain: tuple[float, float] = (0.5, 1.0)
    highlight_knee: float | None = 6.0
    brow_highlight_knee: float | None = 2.0
    shadow_knee: float | None = 6.0
    eye_skin: float = 0.03
    lip_colour: bool = True
    open_lips: bool = True
    lip_ceiling: float | None = 6.0
    lid_colour: float = 0.0
    eye_colour: bool = True
    eye_grow: float = 0.04
    brow_gain: float = 2.0
    occlusion: bool = True
    persona_hair: bool = True
    sharpen: float = 2.5
    sharpen_feather: float = 0.03
    grain: float = 1.0
    grain_reach: float = 0.015
    grain_brows: bool = True
    nose_sharpen: float = 3.0
    nostril_knee: float = 6.0
    lip_detail: float = 1.0
    lid_detail: float = 1.0
    poisson: bool = False
    feather: float = 0.06
    erode: float = 0.03
    mouth: bool = True
    lip_band: float = 0.20
    eyes: str = "driver"


def _knee_map(params: CompositeParams, bands, iod: float):
    """``params.highlight_knee``, or on the bool ``bands`` (:func:`brow_bands`; None: nowhere),
    feathered by BROW_KNEE_FEATHER x ``iod``, ``brow_highlight_knee``: an (H, W) map."""
    knee, brow = params.highlight_knee, params.brow_highlight_knee
    if knee is None or brow is None or bands is None:
        return knee
    w = cv2.GaussianBlur(bands.astype(np.float32), (0, 0), max(0.5, BROW_KNEE_FEATHER * iod))
    return knee + (brow - knee) * w


def composite_face(frame, puppet, coverage, normals, *, driver_oval, driver_points68, puppet_points68=None,
                   driver_normals=None, iris=None, rims=None,
                   params: CompositeParams = CompositeParams()) -> tuple[np.ndarray, np.ndarray]:
    """The puppet composited into the driver's frame: (image (H, W, 3), alpha (H, W)).

    ``frame`` (H, W, 3) the driver's frame; ``puppet`` (H, W, 3) the rendered puppet,
    ``coverage`` (H, W) its anti-aliased coverage, ``normals`` (H, W, 3) its unit camera-space
    normals (needed for ``lighting="sh"`` only, else may be None); ``driver_oval`` (K, 2) the
    driver's face outline and ``driver_points68`` its
    landmarks (frame px); ``puppet_points68`` (68, 2) the puppet's landmarks (output px) or None
    (its lips take the lips' colour and the driver's mouth interior; None: the driver's lips);
    ``driver_normals`` (H, W, 3) the driver's own face normals (its lighting is fitted with them;
    default: the puppet's normals); ``iris`` (3,) the persona's iris-to-skin ratio
    (:func:`~facetex.puppet.eyes.persona_iris`) for the driver's eyeballs drawn in the puppet's
    lids (``params.eyes="driver"``; None: they keep the driver's iris colour); ``rims`` (H, W) in
    [0, 1]: the driver's glasses (:func:`~facetex.geometry.glasses.rim_mask`), kept in front with its
    other occluders (``params.occlusion``).
    All work happens in the face's bounding box."""
    if params.lighting not in LIGHTINGS:
        raise BadInputError(f"unknown lighting {params.lighting!r}: use one of {', '.join(LIGHTINGS)}")
    if params.colour not in COLOURS:
        raise BadInputError(f"unknown colour {params.colour!r}: use one of {', '.join(COLOURS)}")
    if params.eyes not in EYE_SOURCES:
        raise BadInputError(f"unknown eyes {params.eyes!r}: use one of {', '.join(EYE_SOURCES)}")
    frame = np.asarray(frame, np.float32)
    H, W = frame.shape[:2]
    p68 = np.asarray(driver_points68, np.float64)
    pp68 = None if puppet_points68 is None else np.asarray(puppet_points68, np.float64)
    iod = float(np.linalg.norm(p68[36] - p68[45]))
    outline = polygon_mask(driver_oval, (H, W)) > 0.5
    k = int(round(params.erode * iod))
    if k > 0:
        outline = cv2.erode(outline.astype(np.uint8), disc(k)) > 0
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
    bh, bw = rg.shape
    sh = _Shrunk.of(rg.shape, iod, WORK_IOD)
    p_s = sh.points(p68 - [x0, y0])
    rg_s = rg if sh.k == 1 else sh.image(rg) > 0.5
    fr_s = sh.image(fr)
    drv_skin, feats = skin_pixels(fr_s, p_s, rg_s)
    skin_s = rg_s & ~feats if (rg_s & ~feats).sum() >= 16 else rg_s
    occ = None
    if params.occlusion:
        # over the outline only: a highlight on the nose or a birthmark is the driver's face
        occ = sh.back(occlusion_mask(rg_s, drv_skin, feats, p_s, touching=outline_band(rg_s, p_s))) * rg
        if rims is not None:
            occ = np.maximum(occ, np.asarray(rims, np.float32)[box] * rg)
    if params.persona_hair and pp68 is not None:  # the driver's frame shows where the persona's hair is
        # (at ~HAIR_IOD px between the eye corners: at WORK_IOD the grown features cover the temples)
        hs = _Shrunk.of(rg.shape, iod, HAIR_IOD)
        cov = rg if coverage is None else np.asarray(coverage, np.float32)[box] > 0.5
        hair = hs.back(persona_hair(hs.image(pu), hs.points(pp68 - [x0, y0]), hs.mask(rg), area=hs.mask(cov))) * rg
        occ = hair if occ is None else np.maximum(occ, hair)
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
    # each face's brows and its eyes and lips, grown (made once: the brow bands, the sharpening's
    # features and the grain's cut all come from them)
    want_bands = pp68 is not None and (params.brow_highlight_knee is not None or params.grain_brows)
    parts_d = parts_p = None
    if want_bands or params.sharpen > 1 or params.grain > 0:
        parts_d = feature_parts(p68 - [x0, y0], rg.shape)
        parts_p = None if pp68 is None else feature_parts(pp68 - [x0, y0], rg.shape)
    # where either face's brows are: their own highlight knee, and the skin's grain shifted in
    bands = brow_bands(rg, parts_d, parts_p) if want_bands else None
    if params.lighting in ("sh", "stats"):
        # the puppet's eyeballs, lids and brows are where it draws them: at the driver's landmarks the
        # persona's pale lids were kept as white crescents under a dark driver's eyes (FRL 042)
        drawn68 = p68 if pp68 is None else pp68
        fine = None
        if params.mouth_colour_sigma is not None:  # round both faces' lips (the fields' size)
            lips = feature_mask(p_s, rg_s.shape, dilate=MOUTH_FIELD_GROW, parts=("lips",))
            if pp68 is not None:
                lips |= feature_mask(sh.points(pp68 - [x0, y0]), rg_s.shape, dilate=MOUTH_FIELD_GROW, parts=("lips",))
            fine = (cv2.GaussianBlur(lips.astype(np.float32), (0, 0), max(0.5, MOUTH_FIELD_FEATHER * iod / sh.k)),
                    max(1.0, params.mouth_colour_sigma * iod))
        out = transfer_skin_colour(out, fr, pup_skin, drv_skin, sigma=max(1.0, params.colour_sigma * iod), fine=fine,
                                   gain=params.colour_gain, colour=params.colour, shrink=sh.k,
                                   chroma_gain=params.chroma_gain, highlight_knee=_knee_map(params, bands, iod),
                                   # drawn only on a darker persona than the driver
                                   shadows=(lambda: _skin_weights(drawn68 - [x0, y0], rg.shape))
                                   if params.shadow_knee else None, shadow_knee=params.shadow_knee or 1.0,
                                   lids=_scaled(lid_weights(p68 - [x0, y0], rg.shape), params.lid_colour)
                                   if params.lid_colour > 0 else None,
                                   keep=eye_weights(drawn68 - [x0, y0], rg.shape,
                                                    inset=EYE_KEEP_INSET if params.eyes == "driver" else 0.0)
                                   if params.eye_colour else None,
                                   keep_dark=eye_weights(drawn68 - [x0, y0], rg.shape, grow=params.eye_grow,
                                                         spread=EYE_RIM_SPREAD)
                                   if params.eye_colour and params.eye_grow > 0 else None, keep_chroma=False,
                                   # drawn only on a pair whose skins' ratio lets the brow gain apply
                                   brows=(lambda: brow_weights(drawn68 - [x0, y0], rg.shape))
                                   if params.brow_gain > 0 else None, brow_gain=params.brow_gain,
                                   **(lip_regions(p68 - [x0, y0], None if pp68 is None else pp68 - [x0, y0],
                                                  rg.shape, open_lips=params.open_lips) if params.lip_colour else {}),
                                   lip_ceiling=params.lip_ceiling,
                                   # without the driver's eyes either: its lower lash line lies in the
                                   # puppet's zone wherever its eyes sit lower than the puppet draws them
                                   eye_skin=(lambda: eye_skin_weights(drawn68 - [x0, y0], rg.shape,
                                                                      other68=p68 - [x0, y0]))
                                   if params.eye_skin > 0 else None,
                                   eye_skin_sigma=max(1.0, params.eye_skin * iod))
    if params.sharpen > 1 or params.grain > 0:
        # after the colour transfer: a dark persona's detail is small in sRGB until it takes a pale
        # driver's tone (measured before, Williams' puppets were sharpened to 2x the driver's detail).
        # Skin of both at full size: the driver's landmarks (the puppet sits there), features cut out,
        # and only what has the driver's skin colour (its hair, fringe, glasses and the background
        # at the outline would set a far higher target)
        feats_d = parts_d[0] | parts_d[1]
        feats_p = None if parts_p is None else parts_p[0] | parts_p[1]
        skin_full = rg & ~feats_d
        colour_skin = cv2.resize(drv_skin.astype(np.uint8), (bw, bh), interpolation=cv2.INTER_NEAREST) > 0 \
            if sh.k > 1 else drv_skin
        if (skin_full & colour_skin).sum() >= 64:
            skin_full = skin_full & colour_skin
        if params.sharpen > 1:
            cov = np.asarray(coverage, np.float32)[box]
            fsig = max(0.5, params.sharpen_feather * iod)
            where = None if params.sharpen_feather <= 0 else cv2.GaussianBlur(
                skin_full.astype(np.float32), (0, 0), fsig)
            out, _ = match_sharpness(out, fr, skin_full, skin_full, max_gain=params.sharpen, coverage=cov,
                                     where=where)
            if where is not None and feats_p is not None:
                # the features by their own gain: a texture's eyes, brows and lips are softer than a
                # 1000 px frame's and crisper than a soft 256 px video's
                near = cv2.GaussianBlur((feats_p | feats_d).astype(np.float32), (0, 0), fsig)
                # measured without the eyeballs (the driver's are drawn in: the gain must not depend on
                # the puppet's own), grown by the Laplacian's reach
                balls = [cv2.dilate(_eyeballs(q - [x0, y0], rg.shape).view(np.uint8),
                                    np.ones((5, 5), np.uint8)) > 0 for q in (pp68, p68)]
                out, _ = match_sharpness(out, fr, rg & feats_p & ~balls[0], rg & feats_d & ~balls[1],
                                         max_gain=params.sharpen, coverage=cov,
                                         where=np.minimum(1.0 - where, near) * rg)
        if params.grain > 0:  # where even the bounded gain left it smoother than the frame
            if feats_p is not None:  # neither face's features: the frame's lash lines and creases stay out
                skin_full = skin_full & ~feats_p
            # the driver's brow hair stays out
            fill = grain_fill(skin_full, bands, GRAIN_FILL_STEP * iod) if params.grain_brows and bands is not None \
                else None
            if params.grain_reach > 0:  # the bands the persona's resolution lacks, coarsest first
                out, _ = match_grain_bands(out, fr, skin_full, reach=params.grain_reach * iod,
                                           max_amount=params.grain, fill=fill)
            out, _ = match_grain(out, fr, skin_full, max_amount=params.grain, fill=fill)
    if (params.nose_sharpen > 1 or params.nostril_knee > 0) and pp68 is not None:
        nose_p = nose_mask(pp68 - [x0, y0], rg.shape) & rg  # where the puppet's nose is drawn
        nose_d = nose_mask(p68 - [x0, y0], rg.shape) & rg
        if nose_p.sum() >= 16 and nose_d.sum() >= 16:
            where = cv2.GaussianBlur(nose_p.astype(np.float32), (0, 0), max(0.7, 0.04 * iod))
            if params.nose_sharpen > 1:
                out, _ = match_sharpness(out, fr, nose_p, nose_d, max_gain=params.nose_sharpen,
                                         coverage=np.asarray(coverage, np.float32)[box], where=where)
            if params.nostril_knee > 0:
                out = floor_nostrils(out, fr, where, nose_d, knee=params.nostril_knee)
    if params.lip_detail > 0 and params.mouth and pp68 is not None:
        out, _ = match_lip_detail(out, fr, p68 - [x0, y0], pp68 - [x0, y0], max_amount=params.lip_detail)
    if params.lid_detail > 0 and pp68 is not None:
        out, _ = match_lid_detail(out, fr, p68 - [x0, y0], pp68 - [x0, y0], max_amount=params.lid_detail)
    if params.poisson and params.colour == "driver":  # the membrane would bring the driver's tone back
        out = poisson_blend(out, fr, rg)
    if params.mouth and pp68 is not None:
        if params.lip_band > 0:
            out = lift_inner_lips(out, fr, p68 - [x0, y0], pp68 - [x0, y0], band=params.lip_band,
                                  relative=params.colour == "persona" or params.lighting == "none")
        mi, ma = mouth_interior(fr, p68[list(INNER_LIPS)] - [x0, y0], pp68[list(INNER_LIPS)] - [x0, y0], rg.shape)
        ma = ma * rg
        out = _mix(ma, mi, out)
    if params.eyes == "driver" and pp68 is not None:
        # the persona's iris under the frame's light: its iris-to-skin ratio times the driver's skin
        target = None if iris is None else np.asarray(iris, np.float32) * np.median(
            _linear(fr_s[drv_skin]), axis=0)
        ei, ea = eye_interior(fr, p68 - [x0, y0], pp68 - [x0, y0], rg.shape, iris=target)
        out = _mix(ea * rg, ei, out)
    # the persona's own skin tone meets the driver's at the outline: a wider ramp than the driver's
    # colour needs
    feather = params.feather * (PERSONA_FEATHER if params.colour == "persona" else 1.0)
    alpha = inner_feather(rg, max(1.0, feather * iod))
    if occ is not None:  # the driver's occluders stay in front of the puppet, the persona's hair out of it
        alpha = alpha * (1 - occ)
    res = frame.copy()
    res[box] = _mix(alpha, out, fr)
    full = np.zeros((H, W), np.float32)
    full[box] = alpha
    return res, full
