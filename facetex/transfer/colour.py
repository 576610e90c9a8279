"""Detail, not lighting: the content keeps its own low-frequency colour and shading (beyond
the FaceTex paper; issue 22). Pure numpy / OpenCV.

The optimiser and the detail stage move the style's texture, but also some of its colour
and shading (faces turned ashen or towards the style's hue: skin blurred at 0.1 × the eye
distance moved by ΔE 1.2–2.0 on average, 3–4 on some cheeks). This step removes the
low-frequency part of the *change* inside the skin::

    x_t ← x_t − m ⊙ L_m(x_t − x_c),   L_m(d) = G_σ * (m d) / G_σ * m

``L_m`` is a normalised (mask-weighted) Gaussian low-pass over the skin ``m`` only, so the
eyes, brows, hair and background never bleed into it (no halos at the features: they are
not averaged in), and the correction is weighted by the soft skin mask itself, so it fades
out with the transfer's own feathered border. Detail finer than σ (pores, wrinkles, marks)
is kept; ``σ`` is a fraction of the eye distance, as the measure
(:func:`facetex.metrics.lowfreq_skin_delta_e`) blurs at 0.1 × the eye distance.
"""

from __future__ import annotations

import numpy as np

from ..errors import BadInputError
from ..geometry.filters import masked_lowpass

__all__ = ["keep_content_shading", "eye_distance", "SHADING_SIGMA"]

#: σ of the shading step's low-pass, × the eye distance (eye centres). Half of the measure's
#: 0.1: a change kept at σ leaves at most ~8 % of itself in the measure's blur (at σ = 0.1
#: it would leave 25 %), while the detail stage's coarsest band (σ 8 px at a 330 px face
#: width, ≈ 0.06 × the eye distance) is mostly above it.
SHADING_SIGMA = 0.05


def eye_distance(points68) -> float:
    """Distance (px) between the centres of the two eyes (mean of points 36–41 and 42–47)."""
    p = np.asarray(points68, np.float64)
    if p.shape != (68, 2):
        raise BadInputError(f"need 68 landmarks (68, 2), got shape {p.shape}")
    return float(np.linalg.norm(p[42:48].mean(0) - p[36:42].mean(0)))


def keep_content_shading(output, content, skin, sigma: float) -> np.ndarray:
    """``output`` with the low-frequency part (σ px) of its change from ``content`` removed
    inside ``skin`` (soft mask in [0, 1]): the content's colour and shading, the output's
    detail (module doc). Outside the skin the output is returned unchanged."""
    out = np.asarray(output, np.float32)
    con = np.asarray(content, np.float32)
    if out.shape != con.shape or out.ndim != 3:
        raise BadInputError(f"output {out.shape} and content {con.shape} must be the same (H, W, 3) shape")
    m = np.clip(np.asarray(skin, np.float32), 0.0, 1.0)
    low = masked_lowpass(out - con, m, sigma)
    return np.clip(out - m[..., None] * low, 0.0, 1.0)
