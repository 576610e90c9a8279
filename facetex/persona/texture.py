"""Expression-dependent texture synthesis from a persona (Tom Hanks Sec. 5, Figs. 4-7).

Pipeline of the paper, for target fiducials F^T: TPS-warp every photo to F^T (Eq. 1),
refine by collection flow (flow to the projection onto the rank-4 appearance subspace
of the warped stack), then blend Laplacian pyramids with the per-pixel weights of Eq. 3
and collapse.

Fast path (``precomputed=True``, default). Everything target-independent is done
once per persona: each photo is aligned (TPS + collection flow) to the collection's
mean fiducials M (the "neutral frame", at build time), and its Laplacian pyramid and
Laplacian responses are computed there. Per target only the scalar expression weights
change, so each pyramid level of the blend is one matrix-vector product over the
precomputed stack; the blended texture is then warped once by the TPS M -> F^T
(one resampling of one image). Approximations against the paper's per-target
pipeline: (1) the photo-to-target warp TPS(F^T -> F^i) is replaced by
align_i(M -> F^i) o TPS(F^T -> M), which maps the fiducials the same way but differs
between them; (2) the collection flow and the Laplacian responses are computed in the
neutral frame instead of the target frame; (3) pyramid blending and the final warp
are swapped (exact for an affine warp). ``precomputed=False`` runs the paper's
per-target pipeline (one optical flow per photo and target: slow) to measure this.

Eq. 3 indexing: pyramid levels are l = 0 (coarsest, the Gaussian residual) ...
p - 1 (finest), as in the paper. The uniform term tau * l^-beta is infinite at l = 0,
so the coarsest level is blended with expression-independent weights (the limit of the
normalised weights); at l = 1 it equals tau; from l = 2 on it is <= 2^-20.

Paper vs ours (``TextureParams()`` is ours, ``TextureParams.paper()`` the paper's Eq. 3;
leave-out numbers from ``facetex bench persona`` on the LFW Bush and Blair collections):

- Expression weights: regional, normalised, with a per-target measured sigma
  (:mod:`facetex.persona.weights`) instead of one Gaussian on all 98 fiducial coordinates
  with sigma = 10.
- alpha = 0 instead of 1: L^1 gives the photos with the most high-frequency energy (JPEG
  blocks, noise, hard light, hair and collar edges) the largest weight; static and ours both
  lose 0.015-0.025 SSIM with it and it puts white speckles on the chin (zoom sheets).
- Pyramid depth: the coarsest level is ~2 px (the paper does not say). With an 8 px coarsest
  level the 24 x 30 level (mouth opening, eye shape, brow) falls under the uniform term
  (l = 1) and expressions wash out; with ~2 px only the lighting (3 x 4 and 6 x 8 levels)
  is shared by all photos. Measured +0.005-0.015 SSIM; the texture's mean colour varies a
  little more across targets (1.6 instead of 1.2 / 255).
- Confidence: the per-pixel weight is multiplied by each photo's trust in that pixel
  (:func:`facetex.geometry.frontalize.fill_confidence`): its own visibility, feathered;
  0.1 for pixels filled from the mirrored side (they are the other cheek under other light:
  this removes the oval seam of the fill from the blend); 0.25 outside the photo's own face
  outline (collar, flags and background no longer leak into the chin and cheeks).
- Outside the face (grown by 0.3 IOD) the texture is the expression-independent average.
- Detail weights (``TextureParams.detail``): the regional weights spread over 15-60 photos, and
  their average has no iris, whites or lid line (eyes smudged, the puppet's eye region 0.15-0.3
  of the driver's Laplacian variance). The eyes' expression-weighted levels blend the weights
  raised to the 4th power (the same Gaussian, sigma / 2: a few photos) times each photo's
  eye-detail confidence (its eyes' band energy, Eq. 2's L^alpha as one number per photo:
  open, sharp eyes first); the rest of the face's two finest levels the weights squared, and
  its bands up to 8 px get the photos' own band energy back (``restore``, gain <= 3). The
  coarse levels stay the broad average (colour and shading consistent). Leave-out SSIM pays
  for it (a sharp photo's eyes are not the held-out photo's; the average's blur is closer in
  SSIM): on Hugo Chavez (50 photos) eyes gain over static +0.010 -> -0.026, face +0.016 ->
  -0.011, mouth +0.032 -> +0.029 (the 8th power: eyes -0.05; restoring the eyes too: -0.012
  more).
- The weights are normalised per level and region, the coarse uniform part is precomputed,
  and only photos with a weight count (a sparse product over pixel segments grouped by
  region): ~10-25 ms per target for 500 photos on one core.

The "static" texture (and stage d of :func:`average_face`) is the Eq. 3 blend at the mean
fiducials with the paper's global weights (sigma 10) and the parameters' alpha and pyramid:
the average of the whole collection, the baseline "ours" must beat.
"""

from __future__ import annotations

import json
import math
import zlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import cv2
import numpy as np

from .._parallel import available_cpus
from ..errors import BadInputError, BadPersonaError
from ..geometry.gaze import gaze_asymmetry, gaze_weights
from ..geometry.glasses import glasses_bridge_score
from ._packed import Packed
from .align import (
    appearance_subspace,
    collection_flow,
    compose_map_flow,
    face_region,
    project_onto_subspace,
    remap_stack,
    tps_map,
    tps_maps,
)

if TYPE_CHECKING:
    from .collection import Persona

__all__ = [
    "TextureParams",
    "METHODS",
    "STAGES",
    "synthesize_texture",
    "average_face",
    "prepare_persona",
    "expression_similarity",
    "eq3_weights",
    "gaussian_pyramid",
    "laplacian_pyramid",
    "collapse_pyramid",
    "blend_pyramids",
    "pyramid_levels",
    "laplacian_response",
    "frontalize_reference",
    "WEIGHTS",
    "target_weights",
    "blend_textures",
    "expression_model",
    "sequence_weights",
    "blend_weights",
]

METHODS = ("ours", "static", "weighted", "prewarp")
STAGES = ("a", "b", "c", "d")


@dataclass(frozen=True)
class TextureParams:
    """Parameters of the texture blend: the paper's Eq. 3 constants (alpha, beta, tau) = (1, 20, 1),
    sigma = 10 (Tom Hanks Sec. 6) and ours (module docstring).

    weights: "regional" (ours, default, :mod:`facetex.persona.weights`) or "global" (the paper's
    Eq. 2/3: ``sigma``, alpha 1); neighbours: K of the regional weights' adaptive sigma;
    max_photos: at most this many photos per region and target (regional weights);
    alpha: exponent of the Laplacian response L in Eq. 3, None = 1 with the global weights (the
    paper) and 0 with the regional ones (measured: L^1 favours the photos with the most
    high-frequency energy, i.e. JPEG blocks, noise and harsh light, and costs 0.015-0.025
    leave-out SSIM); min_level_side: the pyramid's coarsest level (px, smaller side);
    mirror_weight / face_support / visibility_floor: the per-photo confidence
    (:func:`facetex.geometry.frontalize.fill_confidence`); regions: the weight regions;
    detail: (region, power, levels): the finest ``levels`` pyramid levels of ``region`` blend its
    weights raised to ``power`` (:func:`facetex.persona.weights.detail_weights`: the detail
    bands from the few photos nearest the expression, the coarse ones from the broad average;
    the eyes' whole expression-weighted pyramid, the rest of the face's two finest bands);
    eye_quality: exponent of each photo's eye-detail confidence in the eyes' detail weights
    (:meth:`_Prepared.eye_quality`; 0: none); gaze: that confidence is multiplied by
    :func:`facetex.geometry.gaze.gaze_weights` with this sigma (0: off): a sharp photo looking
    sideways gave a puppet whose eyes looked off camera whatever the driver did; glasses: exponent of the penalty of photos with
    eyeglasses in the eyes' and the face's weights (:meth:`_Prepared.glasses_free`; 0: none: a
    collection with a few glasses photos drew the frames as ghost rings round the puppet's eyes);
    restore: (region, levels): the finest ``levels`` bands of ``region`` get their photos' own
    band energy back (:meth:`_Prepared._restore_detail`), the gain at most ``restore_gain``; the
    mouth's too (averaged lips were pale and blurred: dlib read the puppet's mouth opening 0.55-0.7
    as wide as its mesh's; taking the mouth's detail from the few nearest photos instead, as the
    eyes', read as well but cost 0.04 leave-out mouth SSIM on a 44-photo collection, restoring 0.01)."""

    sigma: float = 10.0
    alpha: float | None = None
    beta: float = 20.0
    tau: float = 1.0
    iod_ref: float = 69.12
    min_level_side: int = 2
    laplacian_blur: float = 1.0
    laplacian_floor: float = 1e-3
    use_visibility: bool = True
    visibility_floor: float = 0.02
    mirror_weight: float = 0.1
    face_support: float = 0.25
    regions: tuple = ("mouth", "eyes", "face")
    max_photos: int | None = 32
    weights: str = "regional"
    neighbours: int | tuple = 3
    detail: tuple = (("eyes", 4.0, 5), ("face", 2.0, 2))
    eye_quality: float = 1.5
    gaze: float = 0.3
    glasses: float = 4.0
    restore: tuple = (("face", 3), ("mouth", 3))
    restore_gain: float = 3.0

    def detail_of(self, region: str) -> tuple[float, int]:
        """(power, levels) of ``region``'s detail weights (:attr:`detail`; (1, 0): none)."""
        for name, power, levels in self.detail:
            if name == region:
                return float(power), int(levels)
        return 1.0, 0

    @property
    def alpha_(self) -> float:
        """alpha in effect (see the class docstring)."""
        if self.alpha is not None:
            return float(self.alpha)
        return 1.0 if self.weights == "global" else 0.0

    @classmethod
    def paper(cls, **kw) -> "TextureParams":
        """The paper's Eq. 3 weights: global, sigma 10, alpha 1."""
        return cls(**{"weights": "global", "alpha": 1.0, **kw})

    def stack_key(self) -> tuple:
        """The fields the precomputed stacks depend on (the weights do not)."""
        return (self.alpha_, self.min_level_side, self.laplacian_blur, self.laplacian_floor, tuple(self.regions),
                self.use_visibility, self.visibility_floor, self.mirror_weight, self.face_support)


WEIGHTS = ("regional", "global")
#: per weight region, the multiple of the collection's median glasses score above which a photo's
#: weight falls (:meth:`_Prepared.glasses_free`): the eyes' from 1.25 (faint rims at 1.5), the rest
#: of the face's from 2 (strong frames only: from 1.25 it also took weight from 13 of Williams'
#: 52 photos, none with glasses; from 2, Arroyo's faint rims are still gone)
GLASSES_LEVELS = {"eyes": 1.25, "face": 2.0}


# ------------------------------------------------------------------ pyramids, Eq. 3
def pyramid_levels(shape, min_side: int = 8) -> int:
    """Number of levels p so the coarsest level's smaller side is about ``min_side`` px."""
    s = min(int(shape[0]), int(shape[1]))
    return max(1, int(math.floor(math.log2(max(s, 1) / min_side))) + 1)


def gaussian_pyramid(image: np.ndarray, levels: int) -> list[np.ndarray]:
    """Gaussian pyramid (cv2.pyrDown), finest (the image as float32) first."""
    g = [np.asarray(image, np.float32)]
    for _ in range(levels - 1):
        g.append(cv2.pyrDown(g[-1]))
    return g


def laplacian_pyramid(image: np.ndarray, levels: int) -> list[np.ndarray]:
    """Laplacian pyramid (cv2.pyrDown / pyrUp), finest band first, Gaussian residual last."""
    g = gaussian_pyramid(image, levels)
    pyr = [g[k] - cv2.pyrUp(g[k + 1], dstsize=(g[k].shape[1], g[k].shape[0])) for k in range(levels - 1)]
    pyr.append(g[-1])
    return pyr


def collapse_pyramid(pyr: list[np.ndarray]) -> np.ndarray:
    """Inverse of :func:`laplacian_pyramid` (exact up to float rounding)."""
    img = pyr[-1]
    for band in reversed(pyr[:-1]):
        img = band + cv2.pyrUp(img, dstsize=(band.shape[1], band.shape[0]))
    return img


def laplacian_response(gaussian_level: np.ndarray, *, blur: float = 1.0, floor: float = 1e-3) -> np.ndarray:
    """L of Eq. 3 on one pyramid level: blurred |Laplacian| of the luminance, plus a floor."""
    g = gaussian_level
    if g.ndim == 3:
        g = cv2.cvtColor(np.ascontiguousarray(g, np.float32), cv2.COLOR_RGB2GRAY)
    L = np.abs(cv2.Laplacian(g.astype(np.float32), cv2.CV_32F, ksize=3))
    if blur > 0:
        L = cv2.GaussianBlur(L, (0, 0), blur)
    return L + np.float32(floor)


def expression_similarity(target, fiducials, sigma: float = 10.0, *, scale: float = 1.0) -> np.ndarray:
    """exp(-||F^T - F^i||^2 / 2 sigma^2) per photo (n,), float64; distances times ``scale``."""
    t = np.asarray(target, np.float64)
    f = np.asarray(fiducials, np.float64)
    d2 = ((f - t) ** 2).sum(axis=(-2, -1)) * scale**2
    return np.exp(-d2 / (2.0 * sigma**2))


def _uniform_term(level: int, tau: float, beta: float) -> float:
    return math.inf if level == 0 else tau * float(level) ** (-beta)


def eq3_weights(similarity, laplacian, level: int, *, tau: float = 1.0, beta: float = 20.0,
                alpha: float = 1.0) -> np.ndarray:
    """Unnormalised W^i_jk = (similarity_i + tau l^-beta) (L^i_jk)^alpha  # Eq. 3 (Tom Hanks)

    ``similarity`` (n,), ``laplacian`` (n, ...); ``level`` l with 0 the coarsest. At l = 0
    the uniform term is infinite: returned are its normalisation-equivalent limit L^alpha."""
    s = np.asarray(similarity, np.float64)
    L = np.asarray(laplacian, np.float64) ** alpha
    u = _uniform_term(level, tau, beta)
    a = np.ones_like(s) if math.isinf(u) else s + u
    return a.reshape((-1,) + (1,) * (L.ndim - 1)) * L


#: Outside the face support the finest OUTSIDE_SMOOTH_LEVELS pyramid bands are left out: there
#: (hair, neck, collar, background) every frontalized photo is stretched along the generic
#: surface's steep extension, and the average keeps the streaks it paints.
OUTSIDE_SMOOTH_LEVELS = 2

#: fraction of a target's total expression similarity that the fine pyramid levels sum over
#: exactly (the photos with the smallest similarities that make up the rest are left out)
SPARSE_MASS = 0.995


def _cut_small(similarity: np.ndarray, mass: float = SPARSE_MASS, max_photos: int | None = None) -> np.ndarray:
    """(B, n) similarities with each target's smallest ones that together hold less than
    1 - ``mass`` of its total set to 0, and all but the ``max_photos`` largest."""
    S = np.array(np.atleast_2d(similarity), np.float64)
    if max_photos is not None and max_photos < S.shape[-1]:
        kth = -np.partition(-S, max_photos - 1, axis=-1)[:, max_photos - 1 : max_photos]
        S = np.where(S >= kth, S, 0.0)
    if mass >= 1.0:
        return S
    order = np.argsort(S, axis=-1)  # ascending
    srt = np.take_along_axis(S, order, axis=-1)
    cum = np.cumsum(srt, axis=-1)
    drop = cum < (1.0 - mass) * cum[:, -1:]
    np.put_along_axis(S, order, np.where(drop, 0.0, srt), axis=-1)
    return S


def _level_scalars(similarity: np.ndarray, level: int, tau: float, beta: float) -> np.ndarray:
    """Per-photo factor of Eq. 3 at ``level`` ((n,) or (B, n) for B targets), divided by its
    maximum per target (the normalisation of the weights cancels it; this keeps float32
    away from underflow)."""
    u = _uniform_term(level, tau, beta)
    if math.isinf(u):
        return np.ones(np.shape(similarity), np.float32)
    a = similarity + u
    return (a / np.maximum(a.max(axis=-1, keepdims=True), 1e-300)).astype(np.float32)


def blend_pyramids(pyramids: list[list[np.ndarray]], weights: list[list[np.ndarray]]) -> np.ndarray:
    """Collapse of the per-level weighted average (normalised per pixel) of Laplacian pyramids.

    pyramids[i][k]: level k (finest first) of photo i; weights[i][k]: (h_k, w_k) weights."""
    out = []
    for k in range(len(pyramids[0])):
        num = sum(w[k][..., None] * p[k] for p, w in zip(pyramids, weights))
        den = sum(w[k] for w in weights)[..., None]
        out.append(num / np.maximum(den, 1e-30))
    return collapse_pyramid(out)


# ------------------------------------------------------------------ precomputation
def _confidence(persona: Persona, tp: TextureParams, photos: slice = slice(None)) -> np.ndarray:
    """(n, H, W) float32 confidence of the symmetry-filled frontal images ``photos``
    (:func:`facetex.geometry.frontalize.fill_confidence`; per photo)."""
    from ..geometry.frontalize import fill_confidence

    vis = persona.visibility[photos]
    if not tp.use_visibility:
        return np.ones(vis.shape, np.float32)
    return fill_confidence(vis, persona.points68[photos] if tp.face_support < 1 else None,
                           mirror_weight=tp.mirror_weight, outside_face=tp.face_support, floor=tp.visibility_floor)


def _pyramid_stack(aligned: np.ndarray, conf: np.ndarray, levels: int, tp: TextureParams,
                   out: list[np.ndarray] | None = None) -> list[np.ndarray]:
    """Per level k (finest first): (n, h_k * w_k * 4) float32 of [L' band (3 ch), L'] with
    L' = L^alpha * confidence, so a level of the blend is one matrix-vector product.
    ``out``: preallocated per-level (n, ...) arrays to fill."""
    n = len(aligned)
    stacks = out if out is not None else [None] * levels
    for i in range(n):
        pyr = laplacian_pyramid(aligned[i], levels)
        g = aligned[i]
        c = conf[i]
        for k in range(levels):
            if k > 0:
                if tp.alpha_ != 0:  # the image itself is needed only for the response
                    g = cv2.pyrDown(g)
                c = cv2.pyrDown(c)
            if tp.alpha_ == 0:  # L^0 = 1: the response is not needed
                L = np.array(c, np.float32)
            else:
                L = laplacian_response(g, blur=tp.laplacian_blur, floor=tp.laplacian_floor)
                if tp.alpha_ != 1:
                    L = L ** np.float32(tp.alpha_)
                L = L * c
            if stacks[k] is None:
                stacks[k] = np.empty((n, L.size * 4), np.float32)
            row = stacks[k][i].reshape(L.shape + (4,))
            row[..., :3] = pyr[k] * L[..., None]
            row[..., 3] = L
    return stacks


def _photo_rows(aligned: np.ndarray, conf: np.ndarray, levels: int, tp: TextureParams) -> list[np.ndarray]:
    """One photo's rows of :func:`_pyramid_stack`: per level (finest first) (h_k * w_k * 4,)
    float32 [L' band (3 ch), L'] (the same operations, so the same values)."""
    return [r[0] for r in _pyramid_stack(aligned[None], conf[None], levels, tp)]


def _photo_rows_rgbc(image_conf: np.ndarray, levels: int, tp: TextureParams,
                     work: dict | None = None) -> list[np.ndarray]:
    """:func:`_photo_rows` of a (H, W, 4) float32 [image, confidence] for alpha = 0 (L' = the
    confidence): one 4-channel Gaussian pyramid gives the image's and the confidence's levels
    (the separate pyramids' values up to float rounding, < 1e-6). ``work``: a dict kept between
    calls on same-sized images (one per thread): its buffers are reused (fresh ~1 MB arrays per
    photo cost page faults: 1.4-1.8x slower) and the rows returned are views into them, valid
    until the next call."""
    if tp.alpha_ != 0:
        return _photo_rows(image_conf[..., :3], image_conf[..., 3], levels, tp)
    if work is None:
        work = {}
    if work.get("shape") != (image_conf.shape, levels):
        g = gaussian_pyramid(image_conf, levels)
        work.update(shape=(image_conf.shape, levels), g=g, up=[np.empty_like(x) for x in g],
                    c=[np.empty(x.shape[:2], np.float32) for x in g], m=[np.empty_like(x) for x in g])
    g = work["g"]
    g[0] = np.asarray(image_conf, np.float32)
    for k in range(1, levels):
        cv2.pyrDown(g[k - 1], dst=g[k])
    rows = []
    for k in range(levels):
        h, w = g[k].shape[:2]
        # the 4-channel band, its last channel set to 1, times [c, c, c, c]: [band * c, c] in two
        # OpenCV calls (numpy's broadcast over a 3-channel view was 2-3x slower; same values)
        band = work["up"][k]
        if k < levels - 1:
            cv2.subtract(g[k], cv2.pyrUp(g[k + 1], dst=band, dstsize=(w, h)), dst=band)
        else:
            np.copyto(band, g[k])
        band[..., 3] = 1
        c = cv2.extractChannel(g[k], 3, dst=work["c"][k])
        rows.append(cv2.multiply(band, cv2.merge([c, c, c, c], dst=work["m"][k]), dst=band).reshape(-1))
    return rows


def _single_stack(images: np.ndarray, conf: np.ndarray, tp: TextureParams) -> np.ndarray:
    """(n, H * W * 4) float32 [L' image, L'] at full resolution (single-scale baselines)."""
    n = len(images)
    out = np.empty((n, images[0].shape[0] * images[0].shape[1] * 4), np.float32)
    for i in range(n):
        L = laplacian_response(images[i], blur=tp.laplacian_blur, floor=tp.laplacian_floor)
        if tp.alpha_ != 1:
            L = L ** np.float32(tp.alpha_)
        L = L * conf[i]
        row = out[i].reshape(L.shape + (4,))
        row[..., :3] = images[i] * L[..., None]
        row[..., 3] = L
    return out


def _float16_to_32(src: np.ndarray, out: np.ndarray) -> None:
    """``out[...] = src`` for a 2-D float16 ``src`` (OpenCV's SIMD conversion: 2-3x numpy's)."""
    if src.size == 0:
        return
    r = cv2.multiply(src, 1.0, dst=out, dtype=cv2.CV_32F)  # x * 1 is exact
    if r is not out:
        out[...] = r


def _gemv_blend(stack: np.ndarray, w: np.ndarray, shape) -> np.ndarray:
    r = (w @ stack).reshape(tuple(shape) + (4,))
    return r[..., :3] / np.maximum(r[..., 3:], 1e-30)


class _Segment:
    """Pixels of one pyramid level that belong to the same set of weight regions: their stack
    rows (n, npix * 4) float32 [L' band (3 ch), L'] stored contiguously (so a region's product
    reads only its own pixels), their flat pixel indices and the regions' masks there. ``stack``:
    the (n, npix * 4) float32 array to use (default: a new one)."""

    __slots__ = ("pixels", "cols", "regions", "stack", "masks")

    def __init__(self, pixels: np.ndarray, regions: tuple[int, ...], n: int, masks: np.ndarray,
                 stack: np.ndarray | None = None):
        self.pixels = pixels
        self.cols = (pixels[:, None] * 4 + np.arange(4)).reshape(-1)  # stack columns (4 per pixel)
        self.regions = regions
        self.stack = np.empty((n, len(pixels) * 4), np.float32) if stack is None else stack
        self.masks = np.repeat(masks, 4, axis=1)  # (len(regions), npix * 4) float32


def _small_page_arrays(shapes: list[tuple[int, int]]) -> list[np.ndarray]:
    """Float32 arrays of ``shapes`` in one anonymous memory map whose transparent
    huge pages are off. Why: numpy asks for huge pages for large arrays, and the kernel then
    compacts memory at the first touch (defrag "madvise"): the ~470 MB of a 519-photo persona's
    stacks cost 0.7-1.3 s of system time to fault in with huge pages, 0.2-0.5 s with 4 kB pages
    (the blends read them as fast). The arrays keep the map alive (their base); pickled, they are
    copied like any array."""
    import mmap

    sizes = [-(-int(np.prod(s)) * 4 // 64) * 64 for s in shapes]  # 64-byte aligned starts
    total = max(sum(sizes), 1)
    mem = mmap.mmap(-1, total)
    if hasattr(mmap, "MADV_NOHUGEPAGE"):
        try:
            mem.madvise(mmap.MADV_NOHUGEPAGE)
        except OSError:  # a kernel without transparent huge pages
            pass
    arrays, off = [], 0
    for s, size in zip(shapes, sizes):
        arrays.append(np.frombuffer(mem, np.float32, int(np.prod(s)), off).reshape(s))
        off += size
    return arrays


def _csr(weights: np.ndarray):
    """Row-normalised weights (B, n) as a CSR matrix when sparse enough to pay off."""
    import scipy.sparse as sp

    return sp.csr_array(weights)


def _unpremultiply(r: np.ndarray) -> np.ndarray:
    """(..., 3) colours r[..., :3] / r[..., 3] of (..., 4) float32 rows [c * L', L'] (the
    channels one at a time: numpy broadcasts over a length-3 inner axis slowly)."""
    den = np.maximum(r[..., 3], np.float32(1e-30))
    out = np.empty(r.shape[:-1] + (3,), np.float32)
    for c in range(3):
        np.divide(r[..., c], den, out=out[..., c])
    return out


class _Prepared:
    """Target-independent data of a persona for :func:`synthesize_texture` (see module doc).

    Per pyramid level, the pixels inside the face support are grouped into segments by the
    weight regions whose (feathered) masks reach them; outside the face support (hair,
    background, neck) the texture is the expression-independent average (its stack sum is
    kept), so nothing is stored there."""

    #: photos per work unit of the precomputation (bounds the per-chunk maps to ~24 MB)
    CHUNK = 32
    #: region masks below this are cut (the rest renormalised), so segments stay few
    MASK_CUT = 0.01

    def __init__(self, persona: Persona, tp: TextureParams, progress: Callable | None = None,
                 stored: dict | None = None):
        """``stored``: the persona's stored stacks (:func:`stored_stacks`); used when they were
        made with ``tp``'s stack key and this layout, else the stacks are computed."""
        W, H = persona.size
        n = len(persona)
        self.n = n
        self.shape = (H, W)
        self.tp = tp
        self.levels = pyramid_levels(self.shape, tp.min_level_side)
        self.M = persona.mean_fiducials
        self.points68 = persona.points68.mean(axis=0)
        self.region = face_region(self.points68, self.shape)
        self.level_shapes = [p.shape[:2] for p in laplacian_pyramid(np.zeros((H, W, 3), np.float32), self.levels)]
        self._layout(tp.regions)
        self.static = [np.zeros(h * w * 4, np.float64) for h, w in self.level_shapes]
        built = persona._cache.pop("tps_maps", None)  # left by build_persona; dropped after use
        if built is not None and built.shape[0] != n:
            built = None
        self._persona_ref = persona  # for the lazily computed stages and full-frame stacks
        self._full: dict = {}
        self._bounds = [(i, min(i + self.CHUNK, n)) for i in range(0, n, self.CHUNK)]
        self._stage = {}
        self._single = {}
        self._outside_cache = {}
        self._packed: Packed | None = None  # the stored aligned photos (version-4 file)
        self._aligned_q: np.ndarray | None = None  # the same, unpacked (computed here)
        self._aligned_lsb: np.ndarray | None = None  # their images' 9th bits (computed or stored)
        self._gaze = np.full(n, np.nan)  # each aligned photo's gaze asymmetry (made with the stacks)
        # each photo's eyeglasses bridge score (made with the stacks from the photos, stored with them:
        # a load then need not unpack every photo for it, ~0.4 s of a 519-photo puppet's start)
        self._glasses: np.ndarray | None = None
        if not self._load(stored):
            self._compute(persona, built)
        if progress:
            progress(n=1, stage="precompute")

    def _compute(self, persona: Persona, built: np.ndarray | None) -> None:
        """The stacks and static sums from the photos (alignment, 8-bit quantization, pyramids,
        segment gather)."""
        self._fill(persona, built, None)

    def _fill(self, persona: Persona, built: np.ndarray | None, packed: Packed | None,
              static: list[np.ndarray] | None = None) -> None:
        """The stacks and static sums from the photos aligned now (``packed`` None) or from the
        8-bit aligned photos a .persona stored (``packed``, with their ``static`` sums): the same
        pyramids of the same values."""
        n, tp = self.n, self.tp
        luts = _aligned_lut(tp), _lsb_lut()
        if packed is None:  # what a .persona stores
            self._aligned_q = np.empty((n,) + self.shape + (4,), np.uint8)
            self._aligned_lsb = np.empty((n, _lsb_bytes(self.shape)), np.uint8)
            self._glasses = np.full(n, np.nan)

        def chunk(i0: int, i1: int):
            # one photo at a time through alignment, pyramid, segment gather and the static sums:
            # its rows (~1 MB) stay in cache (a whole chunk's full-frame rows, ~30 MB, did not)
            work = {"q": np.empty(self.shape + (4,), np.uint8)}
            if packed is None:
                align, conf = self._align_maps(i0, i1, None if built is None else built[i0:i1])
            sums = [np.zeros(h * w * 4, np.float64) for h, w in self.level_shapes] if static is None else None
            for i in range(i0, i1):
                if packed is None:
                    q = self._aligned_photo(i, align[i - i0], conf[i - i0], self._aligned_q[i], self._aligned_lsb[i])[0]
                    P = self._persona_ref
                    self._glasses[i] = glasses_bridge_score(P.images[i], P.points68[i])
                else:
                    q = packed.photo(i, work["q"])
                # stored or computed, the stacks are made from the same quantized aligned photo
                ic = _dequantize_aligned(q, self._aligned_lsb[i], luts, work)
                self._gaze[i] = gaze_asymmetry(ic[..., :3], self.points68)
                for k, row in enumerate(_photo_rows_rgbc(ic, self.levels, tp, work)):
                    if sums is not None:  # the same sequential float64 sum as rows.sum(axis=0) over the chunk
                        sums[k] += row
                    r4 = row.reshape(-1, 4)
                    for seg in self.segments[k]:  # gathered straight into the segment's rows
                        np.take(r4, seg.pixels, axis=0, out=seg.stack[i].reshape(-1, 4))
            return sums

        # photos are independent: chunks run on a thread pool (OpenCV, zlib and numpy release the
        # GIL); results do not depend on the thread count (partial sums are added in order)
        bounds = self._bounds
        with ThreadPoolExecutor(max(1, min(len(bounds), available_cpus()))) as pool:
            results = list(pool.map(lambda b: chunk(*b), bounds))
        if static is not None:  # stored with the aligned photos (adding every photo's rows cost ~15 % of a load)
            self.static = [np.array(x, np.float32) for x in static]
            return
        for sums in results:
            for k in range(self.levels):
                self.static[k] += sums[k]
        self.static = [(x / max(n, 1)).astype(np.float32) for x in self.static]  # uniform weights

    def stored(self) -> dict:
        """What a .persona file stores of the stacks (:func:`stored_stacks`): the photos aligned to
        the neutral frame with their confidences, 8-bit and packed (the stacks are rebuilt from them
        at load); computed now when the stacks came from a version-3 file."""
        if self._packed is None:
            if self._aligned_q is None:  # stacks read from a version-3 file: align the photos again
                self._aligned_q, self._aligned_lsb = self._aligned_quantized()
            self._packed = Packed.pack(self._aligned_q, workers=available_cpus())
            self._aligned_q = None  # packed: ~1/3 of the memory
        lo, hi = _conf_range(self.tp)
        arrays = {"texture_aligned": self._packed, "texture_aligned_lsb": self._aligned_lsb}
        arrays.update({f"texture_static_{k}": np.asarray(x, np.float32) for k, x in enumerate(self.static)})
        meta = {"key": _stored_key(self.tp), "aligned": {"conf_range": [lo, hi]}, "static": [x.size for x in self.static]}
        scores = self._glasses_scores()
        # NaN (no score: eyes off the photo) stored as -1: scores are >= 0, stored arrays finite
        arrays["texture_glasses_scores"] = np.where(np.isfinite(scores), scores, -1.0)
        meta["glasses"] = True
        return {"meta": meta, "arrays": arrays}

    def _aligned_photo(self, i: int, m: np.ndarray, conf: np.ndarray, out: np.ndarray,
                       lsb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Photo i and its frontal-frame confidence ``conf`` warped by its sampling map ``m`` to the
        neutral frame through one 4-channel remap (per channel the same values), quantized into
        ``out`` and ``lsb`` (:func:`_quantize_aligned`)."""
        ic = np.empty(self.shape + (4,), np.float32)
        np.multiply(self._persona_ref.images[i], np.float32(1 / 255.0), out=ic[..., :3], casting="unsafe")
        ic[..., 3] = conf
        ic = cv2.remap(ic, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return _quantize_aligned(ic, self.tp, out, lsb)

    def _aligned_quantized(self) -> tuple[np.ndarray, np.ndarray]:
        """(n, H, W, 4) uint8 photos aligned to the neutral frame with their confidences and (n, m)
        uint8 their images' 9th bits (:func:`_quantize_aligned`)."""
        out = np.empty((self.n,) + self.shape + (4,), np.uint8)
        lsb = np.empty((self.n, _lsb_bytes(self.shape)), np.uint8)
        for i0, i1 in self._bounds:
            align, conf = self._align_maps(i0, i1)
            for i in range(i0, i1):
                self._aligned_photo(i, align[i - i0], conf[i - i0], out[i], lsb[i])
        return out, lsb

    def _load(self, stored: dict | None) -> bool:
        """Fill the stacks from ``stored`` (a version-4 file's packed aligned photos, or a version-3
        file's float16 stacks); False (nothing changed) when they do not fit."""
        if not stored or stored["meta"].get("key") != _stored_key(self.tp):
            return False
        arrays = stored["arrays"]
        if "aligned" in stored["meta"]:
            packed, lsb = arrays.get("texture_aligned"), arrays.get("texture_aligned_lsb")
            static = [arrays.get(f"texture_static_{k}") for k in range(self.levels)]
            if (not isinstance(packed, Packed) or packed.shape != (self.n,) + self.shape + (4,)
                    or lsb is None or lsb.shape != (self.n, _lsb_bytes(self.shape))
                    or stored["meta"]["aligned"].get("conf_range") != list(_conf_range(self.tp))
                    or [None if x is None else x.shape for x in static] != [(x.size,) for x in self.static]):
                return False
            self._aligned_lsb = lsb
            g = arrays.get("texture_glasses_scores") if stored["meta"].get("glasses") else None
            if g is not None and g.shape == (self.n,):
                self._glasses = np.where(g >= 0, g, np.nan).astype(np.float64)
            try:
                self._fill(self._persona_ref, None, packed, static)
            except (ValueError, zlib.error) as e:  # a stream whose CRC-32 passed but does not unpack
                raise BadPersonaError(f"corrupt persona file (texture_aligned: {type(e).__name__}: {e}): rebuild it "
                                      "with `facetex persona build`", path=stored.get("path")) from None
            self._packed = packed
            return True
        want = [sum(seg.stack.shape[1] for seg in segs) for segs in self.segments]
        if stored["meta"].get("columns") != want:
            return False
        for k in range(self.levels):
            st, sa = arrays.get(f"texture_stack_{k}"), arrays.get(f"texture_static_{k}")
            if (st is None or sa is None or st.shape != (self.n, want[k])
                    or sa.shape != (self.static[k].size,)):
                return False
        for k, segs in enumerate(self.segments):
            st, c = arrays[f"texture_stack_{k}"], 0
            for seg in segs:
                w = seg.stack.shape[1]
                _float16_to_32(st[:, c:c + w], seg.stack)
                c += w
            self.static[k] = np.array(arrays[f"texture_static_{k}"], np.float32)
        return True

    def _align_maps(self, i0: int, i1: int, maps: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Photos i0..i1's sampling maps into the neutral frame (TPS composed with the collection
        flow) and their frontal-frame confidences."""
        persona = self._persona_ref
        if maps is None:
            maps = tps_maps(persona.fiducials[i0:i1], self.M, self.shape, persona.params.tps_smoothing)
        return compose_map_flow(maps, persona.flows[i0:i1]), _confidence(persona, self.tp, slice(i0, i1))

    def _aligned_stacks(self) -> tuple[np.ndarray, np.ndarray]:
        if "aligned" not in self._full:
            persona = self._persona_ref
            H, W = self.shape
            aligned = np.empty((self.n, H, W, 3), np.float32)
            conf = np.empty((self.n, H, W), np.float32)
            for i0, i1 in self._bounds:
                align, c = self._align_maps(i0, i1)
                aligned[i0:i1] = remap_stack(persona.images[i0:i1], align)
                conf[i0:i1] = remap_stack(c, align)
            self._full["aligned"], self._full["conf_aligned"] = aligned, conf
        return self._full["aligned"], self._full["conf_aligned"]

    @property
    def aligned(self) -> np.ndarray:
        """(n, H, W, 3) float32 photos aligned to the neutral frame (computed on first use)."""
        return self._aligned_stacks()[0]

    @property
    def conf_aligned(self) -> np.ndarray:
        """(n, H, W) float32 their confidences (computed on first use)."""
        return self._aligned_stacks()[1]

    @property
    def conf_frontal(self) -> np.ndarray:
        """(n, H, W) float32 confidences of the frontal photos (computed on first use)."""
        if "conf_frontal" not in self._full:
            self._full["conf_frontal"] = _confidence(self._persona_ref, self.tp)
        return self._full["conf_frontal"]

    def stage_b(self) -> np.ndarray:
        """Fig. 6 b: the mean of the photos TPS-warped to the mean fiducials (the TPS alone),
        computed on first use (the TPS maps are recomputed; chunk sums added in order)."""
        if "b" not in self._stage:
            persona = self._persona_ref
            sums = []
            for i0, i1 in self._bounds:
                maps = tps_maps(persona.fiducials[i0:i1], self.M, self.shape, persona.params.tps_smoothing)
                sums.append(remap_stack(persona.images[i0:i1], maps).sum(axis=0, dtype=np.float64))
            self._stage["b"] = np.clip(np.sum(sums, axis=0) / max(self.n, 1), 0, 1).astype(np.float32)
        return self._stage["b"]

    def _layout(self, regions) -> None:
        """Region masks per level (the face support's complement = the static average) and the
        pixel segments (see :class:`_Segment`)."""
        from .weights import face_support, region_masks

        H, W = self.shape
        base = region_masks(self.points68, (H, W), regions)
        sup = face_support(self.points68, (H, W))
        full = np.concatenate([base * sup[None], (1.0 - sup)[None]])  # last: outside (static)
        self.regions = tuple(regions)
        self.masks, self.segments = [], []
        for k in range(self.levels):
            if k > 0:
                full = np.stack([cv2.pyrDown(x) for x in full])
            m = np.where(full < self.MASK_CUT, 0.0, full).astype(np.float32)
            m /= np.maximum(m.sum(axis=0, keepdims=True), 1e-12)
            self.masks.append(m)
            R = len(regions)
            flat = m[:R].reshape(R, -1) > 0
            code = (flat * (1 << np.arange(R))[:, None]).sum(axis=0)
            segs = []
            for c in np.unique(code[code > 0]):
                pix = np.nonzero(code == c)[0]
                regs = tuple(j for j in range(R) if c >> j & 1)
                segs.append((pix, regs, m[list(regs)].reshape(len(regs), -1)[:, pix].copy()))
            self.segments.append(segs)
        # all segments' stacks in one memory map with small pages (_small_page_arrays)
        shapes = [(self.n, len(pix) * 4) for segs in self.segments for pix, _, _ in segs]
        stacks = _small_page_arrays(shapes)
        stacks = iter(stacks)
        self.segments = [[_Segment(pix, regs, self.n, masks, next(stacks)) for pix, regs, masks in segs]
                         for segs in self.segments]

    def single(self, which: str, persona: Persona) -> np.ndarray:
        if which not in self._single:
            if which == "aligned":
                self._single[which] = _single_stack(self.aligned, self.conf_aligned, self.tp)
            else:
                front = persona.images.astype(np.float32) / 255.0
                self._single[which] = _single_stack(front, self.conf_frontal, self.tp)
        return self._single[which]

    def blend_ours(self, similarity: np.ndarray) -> np.ndarray:
        return self.blend_many(np.asarray(similarity)[None])[0]

    def blend_ours_many(self, similarities: np.ndarray) -> np.ndarray:
        """(B, H, W, 3) blends for B targets' global similarities (B, n) (Eq. 3)."""
        return self.blend_many(np.atleast_2d(similarities))

    def level_masks(self) -> list[np.ndarray]:
        """Per pyramid level (finest first), the (R + 1, h_k, w_k) masks of the weight regions
        and, last, of the outside (static average), summing to 1."""
        return [m.reshape((-1,) + tuple(sh)) for m, sh in zip(self.masks, self.level_shapes)]

    def _outside(self, k: int) -> np.ndarray:
        """Level k's static rows times the outside mask (its finest bands left out: no fine detail
        off the face, where the frontalization paints streaks), cached."""
        if k not in self._outside_cache:
            h, w = self.level_shapes[k]
            outside = self.masks[k][-1].repeat(4)
            if k < OUTSIDE_SMOOTH_LEVELS:
                outside = outside * np.tile(np.array([0, 0, 0, 1], np.float32), h * w)
            self._outside_cache[k] = (self.static[k] * outside).astype(np.float32)
        return self._outside_cache[k]

    def blend_many(self, weights: np.ndarray) -> np.ndarray:
        """(B, H, W, 3) blends for B targets. ``weights``: (B, n) global similarities (the same for
        every region) or (B, R, n) per-region similarities (mixed per pixel by the region masks,
        see :mod:`facetex.persona.weights`).

        Per level and region the Eq. 3 factor (s_i + u_l) is normalised to sum 1 over the photos
        and split as u_l * (sum of all photos' rows, precomputed) + sum_i s_i * row_i; the second
        sum leaves out the photos with the smallest similarities that together hold less than
        1 - :data:`SPARSE_MASS` of a target's total (a sparse product then reads only the
        remaining photos' rows). Each region's product covers only its own pixels."""
        p = self.levels
        S = np.asarray(weights, np.float64)
        if S.ndim == 1:
            S = S[None]
        regional = S.ndim == 3
        if not regional:
            S = np.repeat(S[:, None], len(self.regions), axis=1)
        B, R, n = S.shape
        if R != len(self.regions):
            raise BadInputError(f"{R} region weights for the {len(self.regions)} regions {self.regions}")
        if regional and self.tp.glasses > 0:
            # photos with eyeglasses lose their weight round the eyes: their rims lie in the eyes'
            # and the rest of the face's regions (the eyes' detail weights alone left faint rings)
            S = S.copy()
            for j, g in self.glasses_factors().items():
                S[:, j] *= g
        # per region: the similarities, small ones cut; sparse products when that pays off
        Wn = [_cut_small(S[:, j], SPARSE_MASS, self.tp.max_photos if regional else None)
              for j in range(R if regional else 1)]
        sums = [w.sum(axis=-1) for w in Wn]  # the kept weights sum to 1 (with the uniform term)
        # one (sparse when that pays off) matrix per region; each level only rescales its rows
        def matrix(w):
            return _csr(w.astype(np.float32)) if np.count_nonzero(w) < 0.5 * w.size else w.astype(np.float32)

        mats = [matrix(w) for w in Wn]
        # the finest levels of a region take its detail weights (same totals, so the same scale)
        fine = [(0, mats[j]) for j in range(len(Wn))]
        if regional:
            from .weights import detail_weights

            for j, name in enumerate(self.regions):
                power, nlev = self.tp.detail_of(name)
                q = self.eye_quality() if name == "eyes" and self.tp.eye_quality > 0 else None
                if nlev > 0 and (power != 1 or q is not None):
                    fine[j] = (nlev, matrix(detail_weights(Wn[j], power, q)))
        bands = []
        for k in range(p):
            lvl = p - 1 - k  # paper's l
            h, w = self.level_shapes[k]
            u = _uniform_term(lvl, self.tp.tau, self.tp.beta)
            static = self.static[k]
            if math.isinf(u):
                out = np.broadcast_to(static, (B, h * w * 4))
            else:
                out = np.repeat(self._outside(k)[None], B, axis=0)
                scale = [(1.0 / (sums[j] + n * u)).astype(np.float32)[:, None] for j in range(len(Wn))]
                ucoef = [(n * u / (sums[j] + n * u)).astype(np.float32)[:, None] for j in range(len(Wn))]
                for seg in self.segments[k]:
                    st = static[seg.cols][None] if u > 0 else None
                    if not regional:  # one product, the regions' masks summed
                        acc = mats[0] @ seg.stack
                        acc *= scale[0]
                        if u > 0:
                            acc += ucoef[0] * st
                        acc *= seg.masks.sum(axis=0)[None]
                    else:
                        acc = np.zeros((B, seg.stack.shape[1]), np.float32)
                        for mj, j in zip(seg.masks, seg.regions):
                            num = (fine[j][1] if k < fine[j][0] else mats[j]) @ seg.stack
                            num *= scale[j]
                            if u > 0:
                                num += ucoef[j] * st
                            num *= mj
                            acc += num
                    for ob, ab in zip(out, acc):  # row by row: the 2-D fancy scatter is ~2.5x slower
                        t = ob.take(seg.cols)
                        t += ab
                        ob[seg.cols] = t
            bands.append(_unpremultiply(out.reshape(B, h, w, 4)))
        if regional:
            self._restore_detail(bands, fine, mats)
        return np.stack([collapse_pyramid([b[j] for b in bands]) for j in range(B)])

    def band_energy(self) -> np.ndarray:
        """(levels, R, n) each photo's mean band energy |band|^2 (RGB summed, confidence-weighted)
        per pyramid level and weight region (its mask-weighted pixels), from the stacks, once."""
        if "band_energy" not in self._stage:
            R = len(self.regions)
            num = np.zeros((self.levels, R, self.n))
            den = np.zeros((self.levels, R, self.n))
            for k, segs in enumerate(self.segments):
                for seg in segs:
                    for i0 in range(0, self.n, self.CHUNK):  # a chunk of photos at a time (memory)
                        rows = seg.stack[i0:i0 + self.CHUNK].reshape(-1, len(seg.pixels), 4)
                        c = rows[..., 3]
                        e = (rows[..., 0] ** 2 + rows[..., 1] ** 2 + rows[..., 2] ** 2) / np.maximum(c, 1e-6)
                        for mj, j in zip(seg.masks[:, ::4], seg.regions):  # (band c)^2 / c = |band|^2 c
                            num[k, j, i0:i0 + len(rows)] += e @ mj
                            den[k, j, i0:i0 + len(rows)] += c @ mj
            self._stage["band_energy"] = num / np.maximum(den, 1e-12)
        return self._stage["band_energy"]

    def _restore_detail(self, bands: list[np.ndarray], fine: list, mats: list) -> None:
        """Detail restoration (``tp.restore``; in place on the (B, h, w, 3) ``bands``, finest first;
        ``fine``: per region (levels, weights) of the detail weights, ``mats`` the other levels').

        Averaging photos whose fine detail (pores, creases, lashes) is not aligned to the pixel
        cancels most of it: the blend's band energy is a fraction of what each photo has. Per
        target, level and region, the band is scaled by sqrt(E_photos / E_blend), E_photos the
        photos' own mean band energy there weighted as in the blend (:meth:`band_energy`), E_blend
        the blended band's, the gain clipped to [1, ``tp.restore_gain``] and mixed per pixel by
        the region masks (1 outside the face): the persona's own amount of detail, as Shih et al.
        2014 match local band energies, with the blend's own structure (no photo's noise)."""
        levels = dict(self.tp.restore)
        if not levels:
            return
        E = self.band_energy()
        for k in range(min(self.levels, max(levels.values()))):
            if _uniform_term(self.levels - 1 - k, self.tp.tau, self.tp.beta) > 1e-3:
                continue  # the lighting levels: shared by all photos, nothing cancelled
            b = bands[k]
            B, h, w, _ = b.shape
            m = self.masks[k].reshape(len(self.regions) + 1, -1)  # (R + 1, h * w), last the outside
            gain = np.zeros((B, h * w), np.float32)
            gain += m[-1][None]  # outside the face: unchanged
            bb = b.reshape(B, -1, 3)
            e2 = bb[..., 0] * bb[..., 0] + bb[..., 1] * bb[..., 1] + bb[..., 2] * bb[..., 2]  # (B, h * w)
            for j, name in enumerate(self.regions):
                mj = m[j]
                if k >= levels.get(name, 0):
                    gain += mj[None]
                    continue
                Wj = fine[j][1] if k < fine[j][0] else mats[j]
                Wj = Wj.toarray() if hasattr(Wj, "toarray") else np.asarray(Wj)
                tot = Wj.sum(axis=1)
                e_photos = (Wj @ E[k, j]) / np.maximum(tot, 1e-30)
                e_blend = (e2 @ mj).astype(np.float64) / max(float(mj.sum()), 1e-12)
                g = np.sqrt(e_photos / np.maximum(e_blend, 1e-12))
                g = np.clip(np.where(np.isfinite(g) & (tot > 0), g, 1.0), 1.0, self.tp.restore_gain)
                gain += g.astype(np.float32)[:, None] * mj[None]
            for c in range(3):  # per channel: numpy broadcasts over a length-3 axis slowly
                b[..., c] *= gain.reshape(B, h, w)

    #: pyramid levels (finest = 0) whose band energy measures a photo's eye detail: 2-8 px
    #: structures (lids, iris against the whites) at the 192 x 240 canonical frame
    QUALITY_LEVELS = (1, 2)

    def eye_quality(self) -> np.ndarray:
        """(n,) detail confidence of each photo's eyes: its band energy (levels
        :data:`QUALITY_LEVELS`, RGB, confidence-weighted) inside both eyes' outlines (grown by
        0.1 IOD) over the collection's median, to the power ``tp.eye_quality`` / 2 (the band's
        amplitude to the power ``eye_quality``), clipped to [1/4, 4]. Open, sharp eyes with visible
        whites and iris have the most energy there; shut, blurred or shadowed ones the least
        (the per-pixel L^alpha of Eq. 2 favoured JPEG blocks and noise: one number per photo over
        the eyes does not); times each photo's gaze weight (``tp.gaze``: photos looking sideways
        count less). Computed from the stacks once."""
        key = ("eye_quality", self.tp.eye_quality, self.tp.gaze)
        if key not in self._stage:
            from ..geometry.masks import polygon_mask

            p = self.points68
            iod = float(np.linalg.norm(p[36:42].mean(0) - p[42:48].mean(0)))
            H, W = self.shape
            m = np.maximum(polygon_mask(p[36:42], (H, W)), polygon_mask(p[42:48], (H, W))) > 0.5
            r = max(1, int(round(0.1 * iod)))
            m = cv2.dilate(m.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2))
            m = m.astype(np.float32)
            num = np.zeros(self.n)
            den = np.zeros(self.n)
            for k in range(self.levels):
                if k > 0:
                    m = cv2.resize(m, self.level_shapes[k][::-1], interpolation=cv2.INTER_AREA)
                if k not in self.QUALITY_LEVELS:
                    continue
                inside = m.reshape(-1) > 0.25
                for seg in self.segments[k]:
                    sel = inside[seg.pixels]
                    if not sel.any():
                        continue
                    rows = seg.stack.reshape(self.n, -1, 4)[:, sel].astype(np.float64)
                    c = rows[..., 3]
                    band2 = (rows[..., :3] ** 2).sum(-1) / np.maximum(c, 1e-6)  # |band|^2 c from (band c)^2 / c
                    num += band2.sum(-1)
                    den += c.sum(-1)
            e = num / np.maximum(den, 1e-12)
            med = float(np.median(e)) if np.median(e) > 0 else 1.0
            q = np.clip((e / med) ** (self.tp.eye_quality / 2.0), 0.25, 4.0)
            # not clipped: a sharp photo looking sideways must lose to the next nearest photos even
            # when its expression weight is the largest (the 4th power of the eyes' detail weights)
            self._stage[key] = q * gaze_weights(self._gaze, self.tp.gaze)
        return self._stage[key]

    def glasses_factors(self) -> dict[int, np.ndarray]:
        """{region index: (n,) :meth:`glasses_free` factors} of the regions in
        :data:`GLASSES_LEVELS`, each at its own level: what the blend multiplies their weights by."""
        return {j: self.glasses_free(GLASSES_LEVELS[name]) for j, name in enumerate(self.regions)
                if name in GLASSES_LEVELS}

    def glasses_free(self, level: float) -> np.ndarray:
        """(n,) weight in (0, 1] of each photo by how unlikely it shows eyeglasses
        (:func:`facetex.geometry.glasses.glasses_weights` of the photos' bridge scores from
        ``level`` x their median, exponent ``tp.glasses``), once per level. The frames' rims are
        strong fine detail round the eyes: the eye-detail weights favoured exactly those photos."""
        key = ("glasses", self.tp.glasses, level)
        if key not in self._stage:
            from ..geometry.glasses import glasses_weights

            self._stage[key] = glasses_weights(self._glasses_scores(), level=level, power=self.tp.glasses)
        return self._stage[key]

    def _glasses_scores(self) -> np.ndarray:
        """(n,) every photo's :func:`facetex.geometry.glasses.glasses_bridge_score` (NaN: none):
        made with the stacks or stored with them; computed from the photos otherwise (a file
        from before they were stored)."""
        if self._glasses is None:
            P = self._persona_ref
            self._glasses = np.array([glasses_bridge_score(im, p) for im, p in zip(P.images, P.points68)], np.float64)
        return self._glasses

    @property
    def pyr(self) -> list[np.ndarray]:
        """Per level (finest first) the (n, h * w * 4) full-frame stack rows assembled from the
        segments (zero outside the face support): for inspection and tests, not used by the blend."""
        out = []
        for k, (h, w) in enumerate(self.level_shapes):
            a = np.zeros((self.n, h * w * 4), np.float32)
            for seg in self.segments[k]:
                a[:, seg.cols] = seg.stack
            out.append(a)
        return out

    def nbytes(self) -> int:
        arrs = [*self._full.values(), *self.static, *([] if self._aligned_q is None else [self._aligned_q]),
                *([] if self._aligned_lsb is None else [self._aligned_lsb]),
                *([] if self._packed is None else [self._packed.blob]),
                *(seg.stack for segs in self.segments for seg in segs), *self._single.values()]
        return int(sum(a.nbytes for a in arrs))


#: version of the stacks' computation: stored stacks of another version are recomputed
STACKS_VERSION = 1


def _conf_range(tp: TextureParams) -> tuple[float, float]:
    """(lo, hi) of the confidences' logarithmic 8-bit code: the floor and the largest confidence
    :func:`facetex.geometry.frontalize.fill_confidence` gives (values outside are clipped)."""
    lo = max(float(tp.visibility_floor), 1e-3) if tp.use_visibility else 0.5
    hi = (max(1.0, tp.mirror_weight) * max(1.0, tp.face_support) + max(tp.visibility_floor, 0.0)
          if tp.use_visibility else 2.0)
    return lo, max(hi, 2 * lo)


def _quantize_aligned(ic: np.ndarray, tp: TextureParams, out: np.ndarray | None = None,
                      lsb: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """An aligned (H, W, 4) float32 [image, confidence] quantized: ((H, W, 4) uint8 codes, (m,) uint8
    the image's 9th bits, packed). The image in 1/511 steps: the codes hold its top 8 bits, ``lsb``
    the last one (its max error 0.25/255 at all pyramid levels together, the pyramid being linear;
    8 bits gave 0.5/255 in the textures, which a composite's colour transfer amplified to 1.7/255
    for a dark-skinned persona). The confidence, a relative weight from the floor (0.02) to ~1, on
    a logarithmic 8-bit scale (0.8 % relative error; < 0.01/255 in the textures)."""
    lo, hi = _conf_range(tp)
    out = np.empty(ic.shape, np.uint8) if out is None else out
    q9 = np.rint(np.clip(ic[..., :3], 0, 1) * 511).astype(np.uint16)
    np.right_shift(q9, 1, out=out[..., :3], casting="unsafe")
    bits = np.zeros(ic.shape, np.uint8)
    np.bitwise_and(q9, 1, out=bits[..., :3], casting="unsafe")
    packed = np.packbits(bits.reshape(-1))
    if lsb is None:
        lsb = packed
    else:
        lsb[...] = packed
    c = np.log(np.clip(ic[..., 3], lo, hi) / lo) * (255 / math.log(hi / lo))
    np.rint(c, out=out[..., 3], casting="unsafe")
    return out, lsb


def _lsb_bytes(shape) -> int:
    """Bytes of one aligned photo's packed 9th bits (4 channels of ``shape`` (H, W))."""
    return -(-int(shape[0]) * int(shape[1]) * 4 // 8)


def _aligned_lut(tp: TextureParams) -> np.ndarray:
    """(1, 256, 4) float32 values of :func:`_quantize_aligned`'s codes without the 9th bit (``cv2.LUT``)."""
    lo, hi = _conf_range(tp)
    q = np.arange(256, dtype=np.float64)
    return np.stack([2 * q / 511, 2 * q / 511, 2 * q / 511, lo * (hi / lo) ** (q / 255)], axis=-1)[None].astype(np.float32)


def _lsb_lut() -> np.ndarray:
    """(1, 256, 4) float32: the value of a set 9th bit (1/511, none for the confidence)."""
    lut = np.zeros((1, 256, 4), np.float32)
    lut[0, 1, :3] = 1 / 511
    return lut


def _dequantize_aligned(q: np.ndarray, lsb: np.ndarray, luts: tuple, work: dict | None = None) -> np.ndarray:
    """(H, W, 4) float32 [image, confidence] of :func:`_quantize_aligned`'s (codes, 9th bits);
    ``luts`` = (:func:`_aligned_lut`, :func:`_lsb_lut`); ``work``: buffers reused between calls."""
    work = {} if work is None else work
    if work.get("ic") is None or work["ic"].shape != q.shape:
        work.update(ic=np.empty(q.shape, np.float32), bits=np.empty(q.shape, np.float32))
    ic = cv2.LUT(q, luts[0], dst=work["ic"])
    bits = np.unpackbits(lsb, count=q.size).reshape(q.shape)
    return cv2.add(ic, cv2.LUT(bits, luts[1], dst=work["bits"]), dst=ic)


def _stored_key(tp: TextureParams) -> list:
    """JSON form of what stored stacks depend on (compared with a .persona's header)."""
    return json.loads(json.dumps([STACKS_VERSION, *tp.stack_key()]))


def stored_stacks(persona: Persona) -> dict:
    """{"meta", "arrays"} of the default parameters' texture stacks for a .persona file (computed,
    or taken from the persona's cache): the photos aligned to the neutral frame and their
    confidences, 8-bit and packed (~60 kB per photo); the stacks are rebuilt from them at load,
    which spares the puppet's setup the alignment of every photo (~10 ms per photo and core)."""
    return prepare_persona(persona).stored()


def prepare_persona(persona: Persona, params: TextureParams | None = None, *, progress=None) -> _Prepared:
    """Precompute (once, cached on the persona) the target-independent synthesis data: from
    the stacks stored in its file when they were made with ``params``' stack key."""
    tp = params or TextureParams()
    key = ("prepared", tp.stack_key())
    if key not in persona._cache:
        stored = persona.texture_stacks
        persona._cache[key] = _Prepared(persona, tp, progress, stored)
        if stored is not None and stored["meta"].get("key") == _stored_key(tp):
            persona.texture_stacks = None  # now held by the cache (exported from there by save)
    prep = persona._cache[key]
    if prep.tp != tp:  # same stacks, other weights: a view with these parameters
        import copy

        prep = copy.copy(prep)
        prep.tp = tp
    return prep


def expression_model(persona: Persona, params: TextureParams | None = None):
    """The persona's regional expression model (:func:`facetex.persona.weights.fit_expression_model`),
    cached on the persona."""
    from .weights import fit_expression_model

    tp = params or TextureParams()
    key = ("expression", tp.neighbours, tuple(tp.regions))
    if key not in persona._cache:
        persona._cache[key] = fit_expression_model(persona.fiducials, neighbours=tp.neighbours, regions=tp.regions)
    return persona._cache[key]


def target_weights(persona: Persona, fiducials, params: TextureParams | None = None,
                   sigma: float | None = None) -> np.ndarray:
    """Expression weights of (..., 49, 2) target fiducials against the persona's photos:
    (..., n) global Eq. 2 similarities (``params.weights == "global"``, sigma default 10) or
    (..., R, n) per-region similarities ("regional")."""
    tp = params or TextureParams()
    if tp.weights not in WEIGHTS:
        raise BadInputError(f"unknown weights {tp.weights!r}: use one of {', '.join(WEIGHTS)}")
    if tp.weights == "global":
        sg = _check_sigma(tp.sigma if sigma is None else sigma)
        t = np.asarray(fiducials, np.float64)
        t = t[..., None, :, :] if t.ndim == 3 else t
        return expression_similarity(t, persona.fiducials, sg, scale=_sigma_scale(persona, tp))
    if sigma is not None:
        raise BadInputError("sigma applies to the paper's global weights (weights='global'); the regional "
                            "weights measure theirs: change TextureParams.neighbours instead")
    return expression_model(persona, tp).similarities(fiducials)


def blend_textures(persona: Persona, fiducials, *, params: TextureParams | None = None,
                   sigma: float | None = None) -> np.ndarray:
    """(B, H, W, 3) float32 textures in the persona's neutral frame (its mean fiducials) with the
    expression weights of B targets (B, 49, 2) (Tom Hanks Sec. 6: "we only synthesize textures
    in their neutral expressions ... but use the target expressions to calculate the blending
    weights"); the regional weights by default."""
    tp = params or TextureParams()
    f = np.asarray(fiducials, np.float64)
    if f.ndim == 2:
        f = f[None]
    f = np.stack([_fiducials49(x) for x in f])
    S = target_weights(persona, f, tp, sigma)
    return np.clip(prepare_persona(persona, tp).blend_many(S), 0, 1).astype(np.float32)


def sequence_weights(persona: Persona, fiducials, params: TextureParams | None = None, *,
                     sigma_frames: float = 0.0, range_scale: float = 1.0) -> np.ndarray:
    """(N, R, n) regional weights of a sequence of N target fiducials (N, 49 or 68, 2) for
    :func:`blend_weights`: each frame's weights as :func:`blend_textures` would use them (the
    smallest cut, at most ``params.max_photos`` per region), then, with ``sigma_frames`` > 0,
    made temporally coherent (:func:`facetex.persona.weights.temporal_weights`: a bilateral filter
    over frames and expression distance, ``range_scale`` x the frame's sigma)."""
    from .weights import temporal_weights

    tp = params or TextureParams()
    if tp.weights != "regional":
        raise BadInputError("sequence weights are the regional weights: use TextureParams(weights='regional')")
    f = np.asarray(fiducials, np.float64)
    f = np.stack([_fiducials49(x) for x in f.reshape((-1,) + f.shape[-2:])])
    S = target_weights(persona, f, tp)  # (N, R, n)
    W = np.stack([_cut_small(S[:, j], SPARSE_MASS, tp.max_photos) for j in range(S.shape[1])], axis=1)
    if sigma_frames <= 0:
        return W
    model = expression_model(persona, tp)
    return temporal_weights(W, model.coordinates(f), model.sigmas(f), sigma_frames=sigma_frames,
                            range_scale=range_scale)


def blend_weights(persona: Persona, weights, *, params: TextureParams | None = None) -> np.ndarray:
    """(B, H, W, 3) float32 textures in the persona's neutral frame for B targets' (B, R, n)
    regional weights as made by :func:`sequence_weights` (no further cut to ``max_photos``; the
    blend's sparse cut of the smallest 0.5 % of the mass still applies)."""
    import dataclasses

    tp = dataclasses.replace(params or TextureParams(), max_photos=None)
    W = np.asarray(weights, np.float64)
    if W.ndim == 2:
        W = W[None]
    return np.clip(prepare_persona(persona, tp).blend_many(W), 0, 1).astype(np.float32)


# ------------------------------------------------------------------ synthesis
def _fiducials49(fiducials) -> np.ndarray:
    from ..landmarks import POINTS49_INDEX

    f = np.asarray(fiducials, np.float64)
    if f.shape == (68, 2):
        f = f[POINTS49_INDEX]
    if f.shape != (49, 2) or not np.all(np.isfinite(f)):
        raise BadInputError(f"target fiducials must be finite (49, 2) or (68, 2) (x, y) points, got {f.shape}")
    return f


def frontalize_reference(reference, size) -> tuple[np.ndarray, np.ndarray]:
    """(frontal image float32 (H, W, 3), pose-corrected fiducials (49, 2)) of a reference
    photo (a path or an RGB image)."""
    from ..geometry.frontalize import frontalize
    from ..io import DETECT_MAX_PIXELS, read_image
    from ..landmarks import POINTS49_INDEX, detect_face

    src = None
    if isinstance(reference, (str, bytes)) or hasattr(reference, "__fspath__"):
        src = reference
        reference = read_image(reference, reduce_to=DETECT_MAX_PIXELS)  # only its face is used
    face = detect_face(reference, source=src)
    fr = frontalize(reference, face.points68, size=size)
    return fr.image, np.asarray(fr.points68, np.float64)[POINTS49_INDEX]


def _sigma_scale(persona: Persona, tp: TextureParams) -> float:
    from ..geometry._generic_face import EYE_SPAN

    return tp.iod_ref / (EYE_SPAN * persona.size[0])


def _check_sigma(sigma) -> float:
    s = float(sigma)
    if not (math.isfinite(s) and s > 0):
        raise BadInputError(f"sigma must be a positive number (typically 6-12), got {sigma!r}")
    return s


def _remap(img: np.ndarray, m: np.ndarray) -> np.ndarray:
    return cv2.remap(np.ascontiguousarray(img, np.float32), m[..., 0], m[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def _reference_flow(ref_image: np.ndarray, subspace: np.ndarray, region: np.ndarray, alpha: float,
                    method: str) -> np.ndarray:
    """Flow from the reference to its projection onto the collection's appearance subspace:
    warping the collection's blend by it moves it onto the reference (Tom Hanks Sec. 5)."""
    from ..geometry.flow import optical_flow

    proj = project_onto_subspace(ref_image, subspace, region)
    return optical_flow(ref_image, np.clip(proj, 0, 1), alpha=alpha, method=method)


def _compose(m: np.ndarray, flow: np.ndarray) -> np.ndarray:
    return compose_map_flow(m[None], flow[None])[0]


def _mask_levels(points68: np.ndarray, shape, levels: int, regions) -> list[np.ndarray]:
    from .weights import region_masks

    out = [region_masks(points68, shape, regions)]
    for _ in range(1, levels):
        out.append(np.stack([cv2.pyrDown(x) for x in out[-1]]))
    return out


def _mixed_blend(stack: np.ndarray, S: np.ndarray, lvl: int, tp: TextureParams, shape,
                 masks: np.ndarray | None) -> np.ndarray:
    """One level's blend: global (n,) weights, or (R, n) regional ones mixed by (R, h, w) masks."""
    if S.ndim == 1:
        return _gemv_blend(stack, _level_scalars(S, lvl, tp.tau, tp.beta), shape)
    r = np.zeros(tuple(shape) + (4,), np.float32)
    for j in range(len(S)):
        r += masks[j][..., None] * (_level_scalars(S[j], lvl, tp.tau, tp.beta) @ stack).reshape(r.shape)
    return r[..., :3] / np.maximum(r[..., 3:], 1e-30)


def synthesize_texture(persona: Persona, *, fiducials=None, reference=None, method: str = "ours",
                       sigma: float | None = None, progress: Callable | None = None,
                       params: TextureParams | None = None, precomputed: bool = True,
                       weights: str | None = None) -> np.ndarray:
    """Texture (H, W, 3) float32 in [0, 1] in the canonical frame for target fiducials
    ``fiducials`` (49 or 68 (x, y) points in the canonical frame) or the expression of a
    ``reference`` photo (path or image; its frontalization gives F^T and the final flow).

    ``method``: "ours" (TPS + collection flow + Eq. 3 multi-scale blend), "static" (the
    stage-d average TPS-warped to the target), "weighted" (single-scale Eq. 3 weighted
    average of the unaligned frontal photos), "prewarp" (TPS + collection flow, then a
    single-scale weighted average). ``weights``: "regional" (default, ours) or "global"
    (the paper's Eq. 2/3, ``sigma`` default 10); overrides ``params.weights``.
    ``precomputed=False``: the paper's per-target pipeline (slow; "ours" and "prewarp" only differ).
    """
    import dataclasses

    if method not in METHODS:
        raise BadInputError(f"unknown method {method!r}: use one of {', '.join(METHODS)}")
    if (fiducials is None) == (reference is None):
        raise BadInputError("give exactly one of target fiducials or a reference photo")
    tp = params or TextureParams()
    if weights is not None:
        tp = dataclasses.replace(tp, weights=weights)
    if sigma is not None and tp.weights == "global":
        tp = dataclasses.replace(tp, sigma=_check_sigma(sigma))
        sigma = None
    W, H = persona.size
    ref_img = None
    if reference is not None:
        ref_img, FT = frontalize_reference(reference, persona.size)
    else:
        FT = _fiducials49(fiducials)
    s = target_weights(persona, FT, tp, sigma)
    pp = persona.params
    if not precomputed and method in ("ours", "prewarp"):
        return _synthesize_exact(persona, FT, ref_img, s, method, tp, progress)
    prep = prepare_persona(persona, tp, progress=progress)
    p = prep.levels
    masks = None
    if s.ndim == 2 and method in ("weighted", "prewarp"):  # single-scale blends: the region masks
        masks = _mask_levels(prep.points68, (H, W), 1, tp.regions)[0]
    if method == "weighted":  # no alignment: the frontal photos as they are
        out = _mixed_blend(prep.single("frontal", persona), s, p - 1, tp, (H, W), masks)
        return np.clip(out, 0, 1).astype(np.float32)
    m = tps_map(FT, prep.M, (H, W), pp.tps_smoothing)  # target -> neutral frame
    if method == "static":
        return np.clip(_remap(average_face(persona, "d", params=tp), m), 0, 1)
    if method == "prewarp":
        blend = _mixed_blend(prep.single("aligned", persona), s, p - 1, tp, (H, W), masks)
    else:
        blend = prep.blend_many(s[None])[0]
    if progress:
        progress(n=1, stage="blend")
    if ref_img is not None:
        sub_t = np.stack([_remap(b, m) for b in persona.subspace])
        region_t = _remap(prep.region.astype(np.float32), m) > 0.5
        h = _reference_flow(ref_img, sub_t, region_t, pp.flow_alpha, pp.flow_method)
        m = _compose(m, h)
    return np.clip(_remap(blend, m), 0, 1).astype(np.float32)


def _synthesize_exact(persona: Persona, FT, ref_img, s, method, tp: TextureParams, progress) -> np.ndarray:
    """The paper's per-target pipeline: TPS F^T -> F^i, subspace and collection flow at the
    target, (optionally) the reference flow, then the blend in the target frame."""
    from ..geometry.tps import ThinPlateSpline

    pp = persona.params
    W, H = persona.size
    maps = tps_maps(persona.fiducials, FT, (H, W), pp.tps_smoothing)
    warped = remap_stack(persona.images, maps)
    M = persona.mean_fiducials
    p68 = ThinPlateSpline.fit(M, FT, smoothing=pp.tps_smoothing)(persona.points68.mean(axis=0))
    region = face_region(p68, (H, W))
    subspace, proj = appearance_subspace(warped, region, pp.subspace_rank)
    flows = collection_flow(warped, proj, pp, progress=progress)
    amaps = compose_map_flow(maps, flows)
    if ref_img is not None:
        h = _reference_flow(ref_img, subspace, region, pp.flow_alpha, pp.flow_method)
        hh = np.broadcast_to(h, amaps.shape)
        amaps = compose_map_flow(amaps, hh)
    aligned = remap_stack(persona.images, amaps)
    conf = remap_stack(_confidence(persona, tp), amaps)
    levels = pyramid_levels((H, W), tp.min_level_side)
    masks = _mask_levels(p68, (H, W), levels, tp.regions) if s.ndim == 2 else [None] * levels
    if method == "prewarp":
        out = _mixed_blend(_single_stack(aligned, conf, tp), s, levels - 1, tp, (H, W), masks[0])
        return np.clip(out, 0, 1).astype(np.float32)
    stacks = _pyramid_stack(aligned, conf, levels, tp)
    shapes = [b.shape[:2] for b in laplacian_pyramid(aligned[0], levels)]
    bands = [_mixed_blend(stacks[k], s, levels - 1 - k, tp, shapes[k], masks[k]) for k in range(levels)]
    return np.clip(collapse_pyramid(bands), 0, 1).astype(np.float32)


def average_face(persona: Persona, stage: str = "d", *, params: TextureParams | None = None) -> np.ndarray:
    """The collection's average face (Tom Hanks Fig. 6), (H, W, 3) float32 in [0, 1]:
    a: mean of the frontalized photos; b: after TPS to the mean fiducials; c: after the
    dense (collection-flow) warp; d: the multi-scale Eq. 3 blend at the mean fiducials with
    the paper's global weights (sigma ``params.sigma``), whatever ``params.weights``: the
    average of the whole collection, not of the few photos nearest the mean expression."""
    if stage not in STAGES:
        raise BadInputError(f"unknown average stage {stage!r}: use one of {', '.join(STAGES)}")
    tp = params or TextureParams()
    if stage == "a":
        return (persona.images.astype(np.float32).mean(axis=0) / 255.0).astype(np.float32)
    import dataclasses

    tp = dataclasses.replace(tp, weights="global", alpha=tp.alpha_)
    prep = prepare_persona(persona, tp)
    if stage == "b":
        return prep.stage_b().copy()
    key = stage if stage in "bc" else (stage, tp)
    if key not in prep._stage:
        if stage == "c":
            img = prep.aligned.mean(axis=0)
        else:
            img = prep.blend_many(target_weights(persona, prep.M, tp)[None])[0]
        prep._stage[key] = np.clip(img, 0, 1).astype(np.float32)
    return prep._stage[key].copy()
