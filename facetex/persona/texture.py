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
  more). The mouth's bands are not restored in the persona texture (restoring them cost
  0.009-0.011 leave-out mouth SSIM on the 44-71-photo collections); the puppet's render restores
  them (``facetex.persona.params.RENDER_RESTORE``: pale, blurred lips read badly).
- The weights are normalised per level and region, the coarse uniform part is precomputed,
  and only photos with a weight count (a sparse product over pixel segments grouped by
  region): ~10-25 ms per target for 500 photos on one core.

The "static" texture (and stage d of :func:`average_face`) is the Eq. 3 blend at the mean
fiducials with the paper's global weights (sigma 10) and the parameters' alpha and pyramid:
the average of the whole collection, the baseline "ours" must beat.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Callable

import cv2
import numpy as np

from ..errors import BadInputError
from ._stack_parts import _confidence, _gemv_blend, _pyramid_stack, _single_stack
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
from .params import METHODS, STAGES, WEIGHTS, TextureParams
from .pyramid import (
    SPARSE_MASS,
    _cut_small,
    _level_scalars,
    collapse_pyramid,
    expression_similarity,
    laplacian_pyramid,
    pyramid_levels,
)
from .stacks import prepare_persona

if TYPE_CHECKING:
    from .collection import Persona

__all__ = [
    "synthesize_texture",
    "average_face",
    "frontalize_reference",
    "target_weights",
    "blend_textures",
    "expression_model",
    "sequence_weights",
    "blend_weights",
]

def expression_model(persona: Persona, params: TextureParams | None = None):
    """The persona's regional expression model (:func:`facetex.persona.weights.fit_expression_model`),
    cached on the persona."""
    from .weights import fit_expression_model

    tp = params or TextureParams()
    mix = tp.region_mix()
    key = ("expression", tp.neighbours, tuple(tp.regions), mix)
    if key not in persona._cache:
        persona._cache[key] = fit_expression_model(persona.fiducials, neighbours=tp.neighbours, regions=tp.regions,
                                                   mix=mix)
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
                     sigma_frames: float = 0.0, range_scale: float = 1.0, segments=None) -> np.ndarray:
    """(N, R, n) regional weights of a sequence of N target fiducials (N, 49 or 68, 2) for
    :func:`blend_weights`: each frame's weights as :func:`blend_textures` would use them (the
    smallest cut, at most ``params.max_photos`` per region), then, with ``sigma_frames`` > 0,
    made temporally coherent (:func:`facetex.persona.weights.temporal_weights`: a bilateral filter
    over frames and expression distance, ``range_scale`` x the frame's sigma; ``segments``: shot ids,
    not mixed)."""
    from .weights import temporal_weights

    tp = params or TextureParams()
    if tp.weights != "regional":
        raise BadInputError("sequence weights are the regional weights: use TextureParams(weights='regional')")
    f = np.asarray(fiducials, np.float64)
    f = np.stack([_fiducials49(x) for x in f.reshape((-1,) + f.shape[-2:])])
    coords, sigmas, S = expression_model(persona, tp).evaluate(f)  # the distances once
    W = cut_region_weights(S, tp)  # (N, R, n)
    if sigma_frames <= 0:
        return W
    return temporal_weights(W, coords, sigmas, sigma_frames=sigma_frames, range_scale=range_scale,
                            segments=segments)


def cut_region_weights(similarities, params: TextureParams) -> np.ndarray:
    """(N, R, n) regional similarities with each region's smallest cut as the blend cuts them (the
    photos holding the last 0.5 % of the mass, and all but ``params.max_photos``)."""
    S = np.asarray(similarities)
    return np.stack([_cut_small(S[:, j], SPARSE_MASS, params.max_photos) for j in range(S.shape[1])], axis=1)


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
