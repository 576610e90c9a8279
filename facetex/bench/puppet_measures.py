"""The measures of ``facetex bench puppet`` (see :mod:`facetex.bench.puppet` for their definitions and
targets): mouth slope, eye openness and blinks, cheek ΔE, sharpness, and the per-run score, failed
targets and worst runs."""

from __future__ import annotations

import numpy as np

from ._common import (
    Column,
)

__all__ = [
    "TARGETS",
    "COLUMNS",
    "mouth_slope",
    "eye_aspect_ratio",
    "eye_openness_ratio",
    "blink_correlation",
    "rest_lift_difference",
    "cheek_mask",
    "cheek_delta_e",
    "under_eye_mask",
    "lightness_difference",
    "face_skin_mask",
    "eye_mask",
    "sharpness_ratio",
    "run_score",
    "failed_targets",
    "worst_runs",
    "sheet_frames",
]


ID_THRESHOLD = 0.6
SLOPE_TARGET = 0.8
CORR_TARGET = 0.85
STEP_RATIO_TARGET = 2.0
ID_FRACTION_TARGET = 0.9
PARTIAL_OUTSIDE = 0.1  # a frame is "partial" when this fraction of the face box is outside the frame
ID_STEP = 3  # identity descriptors (the costly measure, ~0.4 s CPU each) on every 3rd frame
ID_PHOTOS = 40  # photos of the collection averaged into its identity reference
EYE_OPEN = 0.75  # the driver's eyes are open when EAR >= this x its 90th percentile
ALPHA_PUPPET = 0.9  # composite pixels counted as the puppet's
CHEEK_RADIUS = 0.12  # x outer eye-corner distance
#: the under-eye patches: discs of this radius, this far below the middle of each lower lid (x outer
#: eye-corner distance): the skin where a dark persona's circles showed as a band on a pale driver
UNDER_EYE_RADIUS = 0.06
UNDER_EYE_DROP = 0.11
N_WORST = 3

#: targets of issue 21 per run: key -> (lower bound or None, upper bound or None)
TARGETS = {
    "mouth_slope": (0.8, 1.3),
    "mouth_r": (0.85, None),
    "cheek_de": (None, 8.0),
    "eye_ratio": (0.8, None),
    "sharp": (0.75, None),
    "id_closer": (0.8, None),
}

COLUMNS = (
    Column("persona", "persona"),
    Column("clip", "driver clip"),
    Column("frames", "frames", "d"),
    Column("lost", "lost", "d"),
    Column("mouth_slope", "mouth slope", ".2f"),
    Column("mouth_r", "mouth r", ".3f"),
    Column("cheek_de", "cheek ΔE", ".1f"),
    Column("under_eye_dl", "under-eye ΔL*", "+.1f"),
    Column("eye_ratio", "eye open ratio", ".2f"),
    Column("eye_r", "eye r", ".2f"),
    Column("sharp", "sharpness ratio", ".2f"),
    Column("sharp_half", "sharpness at ½ size", ".2f"),
    Column("eye_sharp", "eye sharpness", ".2f"),
    Column("id_closer", "closer to persona", ".0%"),
    Column("score", "fail score", ".2f"),
    Column("mouth_detected", "puppet detected", ".0%"),
    Column("step_ratio", "edge ΔE ratio", ".2f"),
    Column("step_ratio_paste", "edge ratio, pasted", ".2f"),
    Column("tex_open", "tex-static open (0-255)", ".1f"),
    Column("rest_lift", "closed-mouth lift Δ", "+.3f"),
    Column("id_puppet", "id dist puppet", ".3f"),
    Column("id_frac", "id < 0.6", ".0%"),
    Column("id_driver", "id dist driver", ".3f"),
    Column("flicker", "flicker", ".2f"),
    Column("fps", "render fps", ".1f"),
)
#: the direction in which a column's value is worse (for the "worst" row)
WORSE = {"lost": "max", "mouth_r": "min", "cheek_de": "max", "eye_ratio": "min", "eye_r": "min", "sharp": "min",
         "sharp_half": "min", "eye_sharp": "min", "id_closer": "min", "score": "max", "mouth_detected": "min",
         "step_ratio": "max",
         "id_puppet": "max", "id_frac": "min", "id_driver": "min", "flicker": "max", "fps": "min",
         "rest_lift": "max", "under_eye_dl": "abs"}


def _pearson(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 3 or a[ok].std() == 0 or b[ok].std() == 0:
        return float("nan")
    return float(np.corrcoef(a[ok], b[ok])[0, 1])


def mouth_slope(driver, puppet) -> float:
    """Least-squares slope of ``puppet`` on ``driver`` (frames where both are finite): 1 when the
    puppet's mouth opens exactly as far as the driver's, 0 when it does not follow."""
    a, b = np.asarray(driver, float), np.asarray(puppet, float)
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 3 or a[ok].std() == 0:
        return float("nan")
    return float(np.polyfit(a[ok], b[ok], 1)[0])


# --------------------------------------------------------------------------- measures
def eye_aspect_ratio(points68) -> np.ndarray:
    """Eye aspect ratio (Soukupová & Čech 2016) per face, the mean of both eyes: (...,) for (..., 68, 2)."""
    p = np.asarray(points68, np.float64)

    def one(e):  # e: (..., 6, 2) = p1..p6 of one eye (dlib 36-41 or 42-47)
        # EAR = (|p2 − p6| + |p3 − p5|) / (2 |p1 − p4|)
        v = np.linalg.norm(e[..., 1, :] - e[..., 5, :], axis=-1) + np.linalg.norm(e[..., 2, :] - e[..., 4, :], axis=-1)
        return v / (2 * np.maximum(np.linalg.norm(e[..., 0, :] - e[..., 3, :], axis=-1), 1e-9))

    return (one(p[..., 36:42, :]) + one(p[..., 42:48, :])) / 2


def eye_openness_ratio(driver_ear, puppet_ear, *, open_level: float = EYE_OPEN) -> float:
    """mean EAR_puppet / mean EAR_driver over the frames where the driver's eyes are open
    (EAR_driver >= ``open_level`` x its 90th percentile) and both are measured; NaN if none."""
    d, p = np.asarray(driver_ear, float), np.asarray(puppet_ear, float)
    if not np.isfinite(d).any():
        return float("nan")
    ok = np.isfinite(d) & np.isfinite(p) & (d >= open_level * np.nanpercentile(d, 90))
    if not ok.any():
        return float("nan")
    # ratio of means over the open frames: robust to single-frame landmark noise
    return float(p[ok].mean() / max(d[ok].mean(), 1e-9))


def rest_lift_difference(driver_points, puppet_points, driver_opening, *, closed: float = 33.0) -> float:
    """Mean mouth-corner lift (:func:`facetex.puppet.motion.mouth_lift`) of the puppet minus the
    driver's, (N, 68, 2) landmarks of each, over the frames where the driver's mouth is most closed
    (``driver_opening`` (N,) at most its ``closed``-th percentile) and both faces were measured:
    > 0 the puppet smiles where the driver does not (a persona's habitual smile); NaN if none."""
    from ..puppet.motion import mouth_lift

    d, p = np.asarray(driver_points, float), np.asarray(puppet_points, float)
    o = np.asarray(driver_opening, float)
    ok = np.isfinite(o) & np.isfinite(d).all(axis=(1, 2)) & np.isfinite(p).all(axis=(1, 2))
    if not ok.any():
        return float("nan")
    shut = ok & (o <= np.percentile(o[ok], closed))
    return float(np.mean(mouth_lift(p[shut]) - mouth_lift(d[shut])))


def blink_correlation(driver_ear, puppet_ear, *, open_level: float = EYE_OPEN) -> float:
    """Pearson r of the EAR series (the puppet blinks with the driver: near 1); NaN when the
    driver never closes its eyes (no frame below ``open_level`` x its 90th percentile): then r
    would only correlate landmark noise."""
    d = np.asarray(driver_ear, float)
    if not np.isfinite(d).any() or not (d[np.isfinite(d)] < open_level * np.nanpercentile(d, 90)).any():
        return float("nan")
    return _pearson(d, puppet_ear)


def _series(row, key) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in row.get(key) or []], float)


def _series_measures(row: dict) -> dict:
    """(Re)compute in ``row`` the measures of its stored per-frame series (mouth slope and r, eye
    openness ratio and blink r) and its fail score: a resumed run gets the current definitions."""
    if row.get("driver_opening") is not None:
        d, p = _series(row, "driver_opening"), _series(row, "puppet_opening")
        row["mouth_slope"], row["mouth_r"] = mouth_slope(d, p), _pearson(d, p)
    if row.get("driver_ear") is not None:
        d, p = _series(row, "driver_ear"), _series(row, "puppet_ear")
        row["eye_ratio"], row["eye_r"] = eye_openness_ratio(d, p), blink_correlation(d, p)
        row["driver_blink_frames"] = int((d < EYE_OPEN * np.nanpercentile(d, 90)).sum()) if np.isfinite(d).any() \
            else 0
    row["score"], row["failed"] = run_score(row), failed_targets(row)
    return row


def _disc(shape, centre, radius) -> np.ndarray:
    h, w = shape[:2]
    yy, xx = np.mgrid[:h, :w]
    return (xx - centre[0]) ** 2 + (yy - centre[1]) ** 2 <= radius ** 2


def _eye_distance(p68) -> float:
    return float(np.linalg.norm(p68[36] - p68[45]))


def cheek_mask(points68, shape) -> np.ndarray:
    """bool (H, W): the two cheek patches, discs of radius CHEEK_RADIUS x the outer eye-corner
    distance at the centroids of (jaw 1, nostril 31, lower lid 41) and (15, 35, 46)."""
    p = np.asarray(points68, np.float64)
    r = CHEEK_RADIUS * _eye_distance(p)
    return _disc(shape, (p[1] + p[31] + p[41]) / 3, r) | _disc(shape, (p[15] + p[35] + p[46]) / 3, r)


def _lab(image: np.ndarray) -> np.ndarray:
    import cv2

    # float32 RGB in [0, 1] -> CIELAB, L 0..100 (OpenCV: D65, sRGB gamma)
    return cv2.cvtColor(np.clip(np.ascontiguousarray(image, np.float32), 0, 1), cv2.COLOR_RGB2Lab)


def _mean_lab(image, mask) -> np.ndarray:
    """Mean Lab (3,) of ``image``'s pixels on the bool ``mask``: only those pixels are converted
    (the cheek and under-eye measures took two full 1000 px frames to Lab each)."""
    return _lab(np.asarray(image)[mask][None])[0].mean(axis=0)


def cheek_delta_e(image, reference, mask, *, min_pixels: int = 12) -> float:
    """CIE76 ΔE between the mean Lab colours of ``image`` and ``reference`` on ``mask``; NaN when
    fewer than ``min_pixels`` pixels."""
    m = np.asarray(mask, bool)
    if m.sum() < min_pixels:
        return float("nan")
    # ΔE*ab (CIE76) = ||mean Lab(image) − mean Lab(reference)||
    return float(np.linalg.norm(_mean_lab(image, m) - _mean_lab(reference, m)))


def under_eye_mask(points68, shape) -> np.ndarray:
    """bool (H, W): the skin below the eyes, discs of radius UNDER_EYE_RADIUS x the outer eye-corner
    distance, UNDER_EYE_DROP x that distance below the middle of each lower lid (points 40-41, 46-47)."""
    p = np.asarray(points68, np.float64)
    d = _eye_distance(p)
    drop = np.array([0.0, UNDER_EYE_DROP * d])
    return _disc(shape, (p[40] + p[41]) / 2 + drop, UNDER_EYE_RADIUS * d) | \
        _disc(shape, (p[46] + p[47]) / 2 + drop, UNDER_EYE_RADIUS * d)


def lightness_difference(image, reference, mask, *, min_pixels: int = 12) -> float:
    """Mean CIELAB L* (0..100) of ``image`` minus ``reference``'s on ``mask``: < 0 darker; NaN when
    fewer than ``min_pixels`` pixels. Under the eyes (:func:`under_eye_mask`) it sees what the cheek
    ΔE does not: a dark persona's under-eye circles kept as a dark band on a pale driver."""
    m = np.asarray(mask, bool)
    if m.sum() < min_pixels:
        return float("nan")
    return float(_mean_lab(image, m)[0] - _mean_lab(reference, m)[0])


def face_skin_mask(points68, shape) -> np.ndarray:
    """bool (H, W): the face inside the jaw line and the brows, without the eyes (dilated by
    0.1 x eye distance), the brows (0.12 x thick) and the lips (dilated 0.1 x), eroded 0.05 x
    from the outline (the composite's edge)."""
    import cv2

    p = np.asarray(points68, np.float64)
    h, w = shape[:2]
    iod = _eye_distance(p)
    m = np.zeros((h, w), np.uint8)
    cv2.fillPoly(m, [np.round(cv2.convexHull(p[:27].astype(np.float32))[:, 0]).astype(np.int32)], 1)
    m = cv2.erode(m, _ellipse(0.05 * iod))
    cut = np.zeros((h, w), np.uint8)
    for poly in (p[36:42], p[42:48], p[48:60]):
        cv2.fillPoly(cut, [np.round(poly).astype(np.int32)], 1)
    cut = cv2.dilate(cut, _ellipse(0.1 * iod))
    for brow in (p[17:22], p[22:27]):
        cv2.polylines(cut, [np.round(brow).astype(np.int32)], False, 1, max(1, int(round(0.12 * iod))))
    return (m > 0) & (cut == 0)


def eye_mask(points68, shape) -> np.ndarray:
    """bool (H, W): both eye outlines dilated by 0.1 x the eye distance."""
    import cv2

    p = np.asarray(points68, np.float64)
    m = np.zeros(shape[:2], np.uint8)
    for poly in (p[36:42], p[42:48]):
        cv2.fillPoly(m, [np.round(poly).astype(np.int32)], 1)
    return cv2.dilate(m, _ellipse(0.1 * _eye_distance(p))) > 0


def _ellipse(radius: float) -> np.ndarray:
    from ..geometry.masks import disc

    return disc(max(1, int(round(radius))))


def _laplacian_variance(image: np.ndarray, mask: np.ndarray) -> float:
    import cv2

    g = cv2.cvtColor(np.ascontiguousarray(image, np.float32), cv2.COLOR_RGB2GRAY) if image.ndim == 3 else \
        np.asarray(image, np.float32)
    # ∇²I with the 3 x 3 kernel [[0, 1, 0], [1, −4, 1], [0, 1, 0]]; its variance on the mask
    return float(cv2.Laplacian(g, cv2.CV_32F, ksize=1)[mask].var())


def sharpness_ratio(image, reference, mask, *, min_pixels: int = 30, scale: float = 1.0) -> float:
    """Var(∇² image) / Var(∇² reference) on the same ``mask`` (luminance, 3 x 3 Laplacian): 1 when
    as sharp as the reference, < 1 softer; NaN when the mask is too small or the reference flat.
    ``scale`` < 1: both images first resized by it (``cv2.INTER_AREA``), the mask with them (area
    share > 0.5): the detail a step coarser than the pixel, which a pixel-scale grain alone does not
    give (a puppet drawn from ~100 px photos on a 1000 px frame)."""
    m = np.asarray(mask, bool)
    if scale != 1.0:
        import cv2

        def small(x):
            return cv2.resize(np.ascontiguousarray(x, np.float32), None, fx=scale, fy=scale,
                              interpolation=cv2.INTER_AREA)

        image, reference, m = small(image), small(reference), small(m.astype(np.float32)) > 0.5
    if m.sum() < min_pixels:
        return float("nan")
    ref = _laplacian_variance(reference, m)
    return _laplacian_variance(image, m) / ref if ref > 1e-12 else float("nan")


def _margin(key: str, value) -> float:
    """Signed relative distance of ``value`` inside the target of ``key``: the smaller of
    (v − lo) / lo and (hi − v) / hi over its bounds, >= 0 when met, < 0 beyond a bound; NaN when
    not measured."""
    lo, hi = TARGETS[key]
    if value is None or not np.isfinite(value):
        return float("nan")
    return min((value - lo) / abs(lo) if lo is not None else float("inf"),
               (hi - value) / abs(hi) if hi is not None else float("inf"))


def _shortfall(key: str, value) -> float:
    """Relative distance of ``value`` beyond the target of ``key`` (0 when met, 1 when missing):
    below a lower bound (lo − v) / lo, above an upper bound (v − hi) / hi."""
    m = _margin(key, value)
    return 1.0 if np.isnan(m) else max(0.0, -m)


def run_score(row) -> float:
    """Σ over :data:`TARGETS` of (1 if failed) + relative shortfall: 0 when every target is met."""
    s = [_shortfall(k, row.get(k)) for k in TARGETS]
    return float(sum((v > 0) + v for v in s))


def failed_targets(row) -> list[str]:
    """The :data:`TARGETS` keys ``row`` misses."""
    return [k for k in TARGETS if _shortfall(k, row.get(k)) > 0]


def headroom(row) -> tuple[float, str | None]:
    """(smallest relative margin, its target key) of a run meeting every target: how close it
    came to failing (:func:`_margin`); (-inf, None) when a target is missed."""
    margins = {k: _margin(k, row.get(k)) for k in TARGETS}
    if not all(m >= 0 for m in margins.values()):
        return float("-inf"), None
    key = min(margins, key=margins.get)  # ties: the first target
    return margins[key], key


def worst_runs(rows, n: int = N_WORST) -> list[int]:
    """Indices of the ``n`` worst rows: those missing a target by highest :func:`run_score`
    (ties in row order), then, when fewer than ``n`` miss one, the runs closest to a target
    (smallest :func:`headroom`): the sheets to look at are the three worst runs whatever passed."""
    scores = [run_score(r) for r in rows]
    failing = sorted((i for i in range(len(rows)) if scores[i] > 0), key=lambda i: (-scores[i], i))
    passing = sorted((i for i in range(len(rows)) if scores[i] == 0), key=lambda i: (headroom(rows[i])[0], i))
    return (failing + passing)[:n]


def _worst_value(key: str, values: list):
    vals = [v for v in values if isinstance(v, (int, float)) and np.isfinite(v)]
    if not vals:
        return float("nan")
    if key in TARGETS and TARGETS[key][0] is not None and TARGETS[key][1] is not None:
        centre = sum(TARGETS[key]) / 2
        return max(vals, key=lambda v: (_shortfall(key, v), abs(v - centre)))
    how = WORSE.get(key)
    if how == "abs":  # too dark and too light alike: the farthest from 0
        return max(vals, key=abs)
    return min(vals) if how == "min" else max(vals) if how == "max" else float("nan")


def sheet_frames(opening) -> list[int]:
    """Frame indices (most closed, widest open, middle) of the driver's mouth ``opening`` (NaN =
    not measured): the middle one is nearest the mean of the two extremes; evenly spread when
    nothing was measured."""
    o = np.asarray(opening, float)
    n = len(o)
    if not np.isfinite(o).any():
        return [0, n - 1, n // 2]
    lo, hi = int(np.nanargmin(o)), int(np.nanargmax(o))
    d = np.abs(o - (o[lo] + o[hi]) / 2)
    d[[lo, hi]] = np.inf
    d[~np.isfinite(d)] = np.inf
    mid = int(np.argmin(d)) if np.isfinite(d).any() else n // 2
    return [lo, hi, mid]


