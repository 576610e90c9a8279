"""FaceTex evaluation metrics (§3.1 of Kaur, Zhang & Dana 2017), numpy in, floats out.

- :func:`landmark_error` — E(a, b), "mean square error of the landmarks" on the 66
  FaceTex landmarks, at the paper's 1000 px working size.
- :func:`texture_similarity` — S(a, b), Eq. 8 averaged over three skin patches.
- :func:`identity_distance` — beyond the paper: distance of face-recognition
  descriptors (dlib convention: < 0.6 means the same person).

Beyond the paper, to see whether texture really moved and nothing else did:

- :func:`skin_detail` — std (0–255) of a σ = 2 px high-pass of the luminance in the same
  three skin patches, at the image's native resolution (pores, fine wrinkles, stubble);
- :func:`protected_change` — mean |Δ| (0–255) over eyes, brows and lips;
- :func:`background_change` — mean |Δ| (0–255) outside the face;
- :func:`lowfreq_skin_delta_e` — ΔE (CIELAB, L 0..100) of the skin's colour and shading,
  both images blurred at 0.1 × the eye distance over the skin only (issue 22: detail, not
  lighting);
- :func:`hair_leakage` — structure-tensor coherence of the change image on the forehead
  (hair strands are oriented, pores are not);
- :func:`dark_speck_density` on :func:`stubble_regions` — dark specks per 1000 px on the
  upper lip and chin (stubble);
- :func:`skin_coverage` — fraction of the content's skin that changed;
- :func:`mark_survival` — the content's marks (moles, spots) kept and the style's arrived;
- in :func:`transfer_metrics`: ``S_style_gain`` = S(xt, xs) − S(xc, xs) (the move towards
  the style compared with doing nothing) and ``detail_ratio`` = detail(output) / detail(the
  style aligned onto the content), ``detail_moved`` = (detail(output) − detail(content)) /
  (detail(style) − detail(content)) per patch (the fraction of the way from the content's
  fine-detail level to the style's own), ``stubble_moved`` likewise for dark specks.

The implementation is in private modules by topic: :mod:`._paper` (E, S, identity),
:mod:`._detail` (fine detail, protected and background change), :mod:`._issue22` (detail,
not lighting) and :mod:`._transfer` (all of them for one transfer). Use the names here.
"""

from __future__ import annotations

from ._detail import (
    DETAIL_SIGMA,
    MIN_SKIN_FRACTION,
    background_change,
    face_area_mask,
    protected_change,
    skin_detail,
)
from ._issue22 import (
    CHANGED_LEVEL,
    COHERENCE_RHO,
    LOWFREQ_SIGMA,
    SPECK_AREA,
    SPECK_DEPTH,
    SPECK_SIGMA,
    dark_speck_density,
    detail_moved,
    forehead_mask,
    hair_leakage,
    lowfreq_skin_delta_e,
    mark_survival,
    skin_coverage,
    structure_coherence,
    stubble_leakage,
    stubble_regions,
)
from ._paper import (
    METRICS_MAX_PIXELS,
    PATCH_SIZE,
    SKIN_PATCHES,
    WORKING_SIZE,
    LandmarkError,
    identity_distance,
    landmark_error,
    landmark_error_points,
    normalized_correlation,
    skin_patch_frames,
    skin_patches,
    texture_similarity,
    working_scale,
)
from ._transfer import (
    transfer_metrics,
)

__all__ = [
    "WORKING_SIZE",
    "METRICS_MAX_PIXELS",
    "PATCH_SIZE",
    "SKIN_PATCHES",
    "LandmarkError",
    "landmark_error_points",
    "working_scale",
    "landmark_error",
    "normalized_correlation",
    "skin_patch_frames",
    "skin_patches",
    "texture_similarity",
    "DETAIL_SIGMA",
    "MIN_SKIN_FRACTION",
    "skin_detail",
    "protected_change",
    "face_area_mask",
    "background_change",
    "identity_distance",
    "transfer_metrics",
    "LOWFREQ_SIGMA",
    "CHANGED_LEVEL",
    "SPECK_SIGMA",
    "SPECK_DEPTH",
    "SPECK_AREA",
    "COHERENCE_RHO",
    "lowfreq_skin_delta_e",
    "forehead_mask",
    "structure_coherence",
    "hair_leakage",
    "stubble_regions",
    "dark_speck_density",
    "stubble_leakage",
    "skin_coverage",
    "mark_survival",
    "detail_moved",
]
