"""Detail, not lighting: the content keeps its own low-frequency colour and shading (beyond
the FaceTex paper; issue 22). Pure numpy / OpenCV.

The optimiser and the detail stage move the style's texture, but also some of its colour
and shading (faces turned ashen or towards the style's hue: skin blurred at 0.1 × the eye
distance moved by ΔE 1.2–2.0 on average, 3–4 on some cheeks). This step removes the
low-frequency part of the *change* ``d = x_t − x_c`` inside the skin, split into its
luminance ``y = w·d`` (BT.601 weights) and its chroma ``d − y 1``::

    x_t ← x_t − m ⊙ (L_m,σc(d − y 1) + L_m,σy(y) 1),   L_m,σ(a) = G_σ * (m a) / G_σ * m

``L_m`` is a normalised (mask-weighted) Gaussian low-pass over the skin ``m`` only, so the
eyes, brows, hair and background never bleed into it (no halos at the features: they are
not averaged in), and the correction is weighted by the soft skin mask itself, so it fades
out with the transfer's own feathered border. The colour cast goes at a small σc; the
shading at a larger σy, so the style's mid-scale relief (folds, the modelling of pores into
skin texture that Eq. 8's S(xt, xs) sees) stays: on FRL 083 ← 037 the measured ΔE went
1.32 → 0.32 with σc = 0.05, σy = 0.15 (× the eye distance) and the S gain +0.074 → +0.050,
where one σ of 0.05 for both gave ΔE 0.19 but S gain +0.020.
"""


from __future__ import annotations

import numpy as np

from .. import landmarks
from ..errors import BadInputError
from ..geometry.filters import masked_lowpass
from ..io import LUMA_BT601

__all__ = ["keep_content_shading", "eye_distance", "SHADING_SIGMA", "COLOUR_SIGMA"]

#: σ of the shading step's low-pass of the luminance change, × the eye distance (eye centres)
SHADING_SIGMA = 0.15
#: σ of its low-pass of the chroma change (colour cast): half of the measure's 0.1 — a change
#: kept at σ leaves at most ~8 % of itself in the measure's blur; the chroma is invisible to S
COLOUR_SIGMA = 0.05


def eye_distance(points68) -> float:
    """Distance (px) between the centres of the two eyes (mean of points 36–41 and 42–47)."""
    p = np.asarray(points68, np.float64)
    if p.shape != (68, 2):
        raise BadInputError(f"need 68 landmarks (68, 2), got shape {p.shape}")
    return landmarks.eye_distance(p)


def keep_content_shading(output, content, skin, sigma: float, colour_sigma: float | None = None) -> np.ndarray:
    """``output`` with the low-frequency part of its change from ``content`` removed inside
    ``skin`` (soft mask in [0, 1]): luminance below ``sigma`` px, chroma below ``colour_sigma``
    px (default ``sigma``) — the content's colour and shading, the output's detail (module
    doc). Outside the skin the output is returned unchanged."""
    out = np.asarray(output, np.float32)
    con = np.asarray(content, np.float32)
    if out.shape != con.shape or out.ndim != 3 or out.shape[2] != 3:
        raise BadInputError(f"output {out.shape} and content {con.shape} must be the same (H, W, 3) shape")
    m = np.clip(np.asarray(skin, np.float32), 0.0, 1.0)
    d = out - con
    y = d @ LUMA_BT601
    low = masked_lowpass(d - y[..., None], m, sigma if colour_sigma is None else colour_sigma)
    low += masked_lowpass(y, m, sigma)[..., None]
    return np.clip(out - m[..., None] * low, 0.0, 1.0)
