"""What each metric a report shows means: its range, which direction is better, its short title.

The report clips every interval to the metric's range (a landmark error below 0 or a
correlation above 1 is not a possible value) and counts "wins" only for metrics with a
direction. One table, so the page, the figures and the tests agree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["MetricInfo", "metric_info", "TABLE1_METRICS", "PAIR_METRICS"]

INF = math.inf


@dataclass(frozen=True)
class MetricInfo:
    """A metric's short title, its range ``(lo, hi)`` and ``better``: "lower", "higher" or None
    (no direction: e.g. the landmark error to the style, high when the structure is kept)."""

    key: str
    title: str
    lo: float = -INF
    hi: float = INF
    better: str | None = None

    @property
    def bounds(self) -> tuple[float, float]:
        return self.lo, self.hi

    @property
    def arrow(self) -> str:
        return {"lower": " ↓", "higher": " ↑"}.get(self.better or "", "")

    def diff_bounds(self) -> tuple[float, float]:
        """The range of a difference of two values of this metric."""
        return self.lo - self.hi, self.hi - self.lo


_KNOWN = {m.key: m for m in (
    # FaceTex Table 1 (E: mean squared landmark distance, px²; S: Eq. 8 correlation)
    MetricInfo("E_content", "E(xt, xc)", 0, INF, "lower"),
    MetricInfo("E_style", "E(xt, xs)", 0, INF, None),
    MetricInfo("S_content", "S(xt, xc)", -1, 1, None),
    MetricInfo("S_style", "S(xt, xs)", -1, 1, "higher"),
    MetricInfo("E_content_rms_px", "E(xt, xc) RMS px", 0, INF, "lower"),
    MetricInfo("E_style_rms_px", "E(xt, xs) RMS px", 0, INF, None),
    MetricInfo("S_style_none", "S(xc, xs)", -1, 1, None),
    MetricInfo("S_style_gain", "S gain", -2, 2, "higher"),
    # dlib face-descriptor distance (< 0.6: same person)
    MetricInfo("identity_content", "id dist. content", 0, INF, "lower"),
    MetricInfo("identity_style", "id dist. style", 0, INF, None),
    MetricInfo("time_s", "time (s)", 0, INF, "lower"),
    # persona leave-out (Tom Hanks Fig. 5): SSIM, gradient correlation, colour difference
    MetricInfo("face_ssim", "SSIM face", -1, 1, "higher"),
    MetricInfo("mouth_ssim", "SSIM mouth", -1, 1, "higher"),
    MetricInfo("eyes_ssim", "SSIM eyes", -1, 1, "higher"),
    MetricInfo("face_grad_corr", "grad. corr. face", -1, 1, "higher"),
    MetricInfo("face_colour_diff", "colour diff. face", 0, INF, "lower"),
    # puppet runs
    MetricInfo("mouth_slope", "mouth slope", -INF, INF, None),
    MetricInfo("mouth_r", "mouth r", -1, 1, "higher"),
    MetricInfo("cheek_de", "cheek ΔE", 0, INF, "lower"),
    MetricInfo("eye_ratio", "eye open ratio", 0, INF, None),
    MetricInfo("sharp", "sharpness ratio", 0, INF, "higher"),
    MetricInfo("sharp_half", "sharpness at ½ size", 0, INF, "higher"),
    MetricInfo("id_closer", "closer to persona", 0, 1, "higher"),
    MetricInfo("id_puppet", "id dist. puppet", 0, INF, "lower"),
    MetricInfo("id_frac", "id < 0.6", 0, 1, "higher"),
    MetricInfo("flicker", "flicker", 0, INF, "lower"),
    MetricInfo("fps", "render fps", 0, INF, "higher"),
    MetricInfo("fail_score", "fail score", 0, INF, "lower"),
)}

#: Table 1's metrics, in its row order
TABLE1_METRICS = ("E_content", "E_style", "S_content", "S_style")
#: the per-pair table's metrics (Table 1's two "is it working" ones and the identity)
PAIR_METRICS = ("E_content", "S_style", "identity_content")


def metric_info(key: str) -> MetricInfo:
    """The :class:`MetricInfo` of ``key``; a metric not listed gets its range from its name
    (``*_ssim``, ``*_corr``, ``*_r``: [-1, 1]; times, sizes, distances, ``*_de``, ``*_diff``,
    ``*_ratio``, counts: ≥ 0) and no direction."""
    if key in _KNOWN:
        return _KNOWN[key]
    k = key.lower()
    if k.endswith(("_ssim", "_corr", "_r")) or k.startswith(("s_", "ssim")):
        return MetricInfo(key, key, -1, 1)
    if k.endswith(("_s", "_de", "_diff", "_ratio", "_px", "frames", "lost", "_ms", "fps")) or k.startswith(
            ("e_", "identity", "id_", "detail", "stubble", "marks")):
        return MetricInfo(key, key, 0, INF)
    if k in ("coverage",) or k.endswith(("_frac", "_fraction")):
        return MetricInfo(key, key, 0, 1)
    return MetricInfo(key, key)
