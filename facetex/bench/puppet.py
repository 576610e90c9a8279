"""``facetex bench puppet``: persona puppetry driven by talking-face clips (Tom Hanks §4, §6).

The paper has no quantitative puppetry benchmark ("Evaluating a puppetry system objectively
is extremely hard"); we measure what a viewer of the composited videos sees, on **every
persona × every clip** (default: the collections ``DATA/lfw/*`` × the clips ``DATA/grid``,
6 × 6 = 36 runs), and report each run and the **worst** run of every measure, not only means.
Landmarks of a rendered frame are re-detected by dlib (68 points) on a copy upscaled to
720 px (:data:`MEASURE_SIDE`; its predictor is noisy on GRID's ~100 px faces), the driver's the
same way on its own frame; masks are cut at the driver's tracked landmarks (the composite sits
there) and, for the composite, kept where its mask alpha > 0.9 (the puppet, not the driver,
shows there). Per run:

* **mouth**: opening = inner-lip gap / outer-eye-corner distance (:func:`mouth_opening`), on
  every frame; least-squares **slope** of the puppet's on the driver's (target 0.8–1.3) and
  Pearson **r** (target >= 0.85);
* **cheek ΔE** (composite mode): CIE76 ΔE (CIELAB, L 0..100, D65) between the mean Lab colour
  of the composite's two cheek patches and the mean of the driver's own frame on the same
  pixels (:func:`cheek_mask`: discs of radius 0.12 × eye-corner distance at the centroid of
  jaw point 1 (15), nostril 31 (35) and lower lid 41 (46): skin below the eye, lateral to the
  nose), the median over frames; target <= 8;
* **eye openness**: eye aspect ratio (:func:`eye_aspect_ratio`, both eyes averaged) of the
  puppet over the driver's, mean over the frames where the driver's eyes are open (EAR >= 0.75
  × its 90th percentile in the clip): :func:`eye_openness_ratio`, target >= 0.8; **eye r**:
  Pearson r of the two EAR series when the driver blinks (some frame below that level; else
  "–"): :func:`blink_correlation`, near 1 when the puppet blinks with the driver;
* **sharpness**: variance of the Laplacian (3 × 3, luminance) of the composite over the
  driver's own frame on the same face-skin pixels (:func:`face_skin_mask`: inside jaw and
  brows, eyes, brows and lips cut out; :func:`sharpness_ratio`), median over frames; target
  >= 0.75; the same on the eyes (dilated eye outlines) as **eye sharpness** (no target);
* **identity**: on every :data:`ID_STEP`-th tracked frame, the dlib FaceRecognitionNet
  descriptor of the composite is compared with the mean descriptor of the persona's photos
  (up to :data:`ID_PHOTOS` evenly spaced) and with the driver's mean (every 5th frame):
  **closer** = fraction of those frames nearer the persona (no face found counts as not
  closer), target >= 80 %; also the mean distance to each and the fraction < 0.6;
* **boundary colour step**: CIE76 ΔE between bands just inside and just outside the edge of
  the composite mask (alpha 0.5), per angular sector, averaged; divided by the driver's own
  step at the same place in its original frame (target <= 2). The same ratio for the puppet
  pasted without colour/lighting transfer and Poisson blending ("pasted", every 5th frame);
* **expression texture**: mean |texture − static average texture| (0-255) in the mouth region
  of the texture, on the frames where the driver's mouth is open (top quarter of the opening);
* **lost frames** and a **partial-face check** (the first clip slid half out of its frame; every
  frame with >= 10 % of the face box outside must be rejected, every whole face kept);
* **flicker**: mean |frame-to-frame change| (0-255) of the composited face on still frames.

**Worst runs**: per run, each target measure's relative shortfall ``s`` (0 when met; below a
lower bound lo: (lo − v) / lo, above an upper bound hi: (v − hi) / hi; a measure that could not
be taken: 1) gives the score Σ (1[s > 0] + s) over the targets (:func:`run_score`: failed targets
first, then how far). The three highest are the worst runs; their 100 % sheets (driver |
composite | face mode at the driver's most closed, widest-open and middle mouth frames) are
copied as ``worst<k>_<persona>__<clip>.png``.

Outputs: table.md, table.csv, results.json (rows, mean, worst per measure, worst runs); per run
in ``<persona>/``: a contact sheet of 8 frames, the 3-frame sheet at 100 % (``*_sheet3_100.png``),
zoomed crops of the most open-mouth frame, and for the first run a side-by-side MP4;
``runs/<persona>__<clip>.json`` per finished run (reused with ``resume``).
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..errors import BadInputError
from ._common import (Column, ResultStore, check_out_dir, csv_table, image_grid, json_safe, markdown_table, versions,
                      write_text)

__all__ = ["register_bench", "run_bench_puppet", "mouth_slope", "shifted_clip", "eye_aspect_ratio",
           "eye_openness_ratio", "cheek_mask", "cheek_delta_e", "face_skin_mask", "eye_mask", "sharpness_ratio",
           "blink_correlation", "run_score", "failed_targets", "worst_runs", "sheet_frames", "TARGETS"]

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
    Column("eye_ratio", "eye open ratio", ".2f"),
    Column("eye_r", "eye r", ".2f"),
    Column("sharp", "sharpness ratio", ".2f"),
    Column("eye_sharp", "eye sharpness", ".2f"),
    Column("id_closer", "closer to persona", ".0%"),
    Column("score", "fail score", ".2f"),
    Column("mouth_detected", "puppet detected", ".0%"),
    Column("step_ratio", "edge ΔE ratio", ".2f"),
    Column("step_ratio_paste", "edge ratio, pasted", ".2f"),
    Column("tex_open", "tex-static open (0-255)", ".1f"),
    Column("id_puppet", "id dist puppet", ".3f"),
    Column("id_frac", "id < 0.6", ".0%"),
    Column("id_driver", "id dist driver", ".3f"),
    Column("flicker", "flicker", ".2f"),
    Column("fps", "render fps", ".1f"),
)
#: the direction in which a column's value is worse (for the "worst" row)
WORSE = {"lost": "max", "mouth_r": "min", "cheek_de": "max", "eye_ratio": "min", "eye_r": "min", "sharp": "min",
         "eye_sharp": "min", "id_closer": "min", "score": "max", "mouth_detected": "min", "step_ratio": "max",
         "id_puppet": "max", "id_frac": "min", "id_driver": "min", "flicker": "max", "fps": "min"}


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


def cheek_delta_e(image, reference, mask, *, min_pixels: int = 12) -> float:
    """CIE76 ΔE between the mean Lab colours of ``image`` and ``reference`` on ``mask``; NaN when
    fewer than ``min_pixels`` pixels."""
    m = np.asarray(mask, bool)
    if m.sum() < min_pixels:
        return float("nan")
    # ΔE*ab (CIE76) = ||mean Lab(image) − mean Lab(reference)||
    return float(np.linalg.norm(_lab(image)[m].mean(axis=0) - _lab(reference)[m].mean(axis=0)))


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
    import cv2

    k = max(1, int(round(radius)))
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * k + 1, 2 * k + 1))


def _laplacian_variance(image: np.ndarray, mask: np.ndarray) -> float:
    import cv2

    g = cv2.cvtColor(np.ascontiguousarray(image, np.float32), cv2.COLOR_RGB2GRAY) if image.ndim == 3 else \
        np.asarray(image, np.float32)
    # ∇²I with the 3 x 3 kernel [[0, 1, 0], [1, −4, 1], [0, 1, 0]]; its variance on the mask
    return float(cv2.Laplacian(g, cv2.CV_32F, ksize=1)[mask].var())


def sharpness_ratio(image, reference, mask, *, min_pixels: int = 30) -> float:
    """Var(∇² image) / Var(∇² reference) on the same ``mask`` (luminance, 3 x 3 Laplacian): 1 when
    as sharp as the reference, < 1 softer; NaN when the mask is too small or the reference flat."""
    m = np.asarray(mask, bool)
    if m.sum() < min_pixels:
        return float("nan")
    ref = _laplacian_variance(reference, m)
    return _laplacian_variance(image, m) / ref if ref > 1e-12 else float("nan")


def _shortfall(key: str, value) -> float:
    """Relative distance of ``value`` beyond the target of ``key`` (0 when met, 1 when missing)."""
    lo, hi = TARGETS[key]
    if value is None or not np.isfinite(value):
        return 1.0
    if lo is not None and value < lo:
        return (lo - value) / abs(lo)  # below a lower bound: (lo − v) / lo
    if hi is not None and value > hi:
        return (value - hi) / abs(hi)  # above an upper bound: (v − hi) / hi
    return 0.0


def run_score(row) -> float:
    """Σ over :data:`TARGETS` of (1 if failed) + relative shortfall: 0 when every target is met."""
    s = [_shortfall(k, row.get(k)) for k in TARGETS]
    return float(sum((v > 0) + v for v in s))


def failed_targets(row) -> list[str]:
    """The :data:`TARGETS` keys ``row`` misses."""
    return [k for k in TARGETS if _shortfall(k, row.get(k)) > 0]


def worst_runs(rows, n: int = N_WORST) -> list[int]:
    """Indices of the ``n`` rows of highest :func:`run_score` (worst first; ties in row order);
    rows meeting every target are never listed."""
    scores = [run_score(r) for r in rows]
    order = sorted(range(len(rows)), key=lambda i: (-scores[i], i))
    return [i for i in order if scores[i] > 0][:n]


def _worst_value(key: str, values: list):
    vals = [v for v in values if isinstance(v, (int, float)) and np.isfinite(v)]
    if not vals:
        return float("nan")
    if key in TARGETS and TARGETS[key][0] is not None and TARGETS[key][1] is not None:
        centre = sum(TARGETS[key]) / 2
        return max(vals, key=lambda v: (_shortfall(key, v), abs(v - centre)))
    how = WORSE.get(key)
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


def _collection_descriptor(persona_file, limit: int = ID_PHOTOS) -> np.ndarray:
    """Mean dlib descriptor of (up to ``limit`` evenly spaced) photos of a persona's source
    folder, read from its header only (no texture array is loaded)."""
    from ..io import read_image
    from ..landmarks import detect_faces
    from ..nets.dlib_resnet import face_descriptor
    from ..persona.collection import _read_header

    header, _, photos = _read_header(Path(persona_file))
    source = Path(header.get("source", ""))
    names = photos[:: max(1, math.ceil(len(photos) / limit))]
    ds = []
    for n in names:
        if not (source / n).is_file():
            continue
        img = read_image(source / n)
        faces = detect_faces(img, upsample=None)
        if faces:
            ds.append(face_descriptor(img, faces[0].points68))
    if not ds:
        raise BadInputError("no face found in the puppet's photos for the identity reference (its photo folder "
                            "moved?)", path=source)
    return np.mean(ds, axis=0)


#: Frames are upscaled (bicubic) to at least this longer side before measuring landmarks: dlib's
#: 68-point predictor is much noisier on GRID's ~100 px faces (driver and puppet alike).
MEASURE_SIDE = 720


def _frame_measures(image: np.ndarray, *, descriptor: bool = True):
    """(points68 or None, descriptor or None) of the largest face of a frame; landmarks in the
    frame's pixels, measured on a copy upscaled to MEASURE_SIDE."""
    import cv2

    from ..landmarks import detect_faces
    from ..nets.dlib_resnet import face_descriptor

    k = max(1.0, MEASURE_SIDE / max(image.shape[:2]))
    big = cv2.resize(image, None, fx=k, fy=k, interpolation=cv2.INTER_CUBIC) if k > 1 else image
    faces = detect_faces(np.clip(big, 0, 1), upsample=0)
    if not faces:
        return None, None
    p = faces[0].points68
    return (p + 0.5) / k - 0.5, (face_descriptor(image, (p + 0.5) / k - 0.5) if descriptor else None)


def _flicker(frames: list[np.ndarray], alphas: list[np.ndarray], still: np.ndarray) -> float:
    """Mean |I_t − I_{t−1}| (0-255) inside both frames' face masks, over the 'still' frames t."""
    vals = []
    for t in np.flatnonzero(still):
        if t == 0:
            continue
        m = (alphas[t] > 0.5) & (alphas[t - 1] > 0.5)
        if m.sum() < 10:
            continue
        vals.append(255.0 * float(np.abs(frames[t] - frames[t - 1])[m].mean()))
    return float(np.mean(vals)) if vals else float("nan")


def _crop_box(points68: np.ndarray, shape, pad: float = 0.35):
    lo, hi = points68.min(axis=0), points68.max(axis=0)
    c, half = (lo + hi) / 2, (1 + 2 * pad) * max(hi - lo) / 2
    y0, x0 = int(max(0, c[1] - half)), int(max(0, c[0] - half))
    return y0, min(shape[0], int(c[1] + half)), x0, min(shape[1], int(c[0] + half))


def _zoom_regions(p68: np.ndarray, shape) -> dict:
    """Named (y0, y1, x0, x1) boxes around the mouth, the jaw edge, the hairline and a cheek."""
    iod = float(np.linalg.norm(p68[36] - p68[45]))
    r = max(8, int(round(0.4 * iod)))

    def box(c):
        y, x = int(round(c[1])), int(round(c[0]))
        return max(0, y - r), min(shape[0], y + r), max(0, x - r), min(shape[1], x + r)

    brow_top = p68[17:27, 1].min()
    return {
        "mouth": box(p68[48:68].mean(axis=0)),
        "jaw": box(p68[4]),
        "hairline": box([p68[27, 0], brow_top - 0.55 * iod]),
        "cheek": box((p68[1] + p68[31] + p68[41]) / 3),
    }


def _face_region_mask(persona):
    """bool (H, W) mouth region of the persona's texture: the outer lips dilated by 0.15 of the eye distance."""
    import cv2

    from ..geometry.masks import polygon_mask

    p = persona.points68.mean(axis=0)
    W, H = persona.size
    m = polygon_mask(p[48:60], (H, W)) > 0.5
    k = max(1, int(round(0.15 * np.linalg.norm(p[36] - p[45]))))
    return cv2.dilate(m.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * k + 1,) * 2)) > 0


def _driver_measures(clip: Path, ours: list, found: np.ndarray, p68: np.ndarray, cache: Path | None) -> dict:
    """The driver's side (the same for every persona, cached per clip, size and frame count):
    re-detected landmarks (n, 68, 2) (NaN where not found) and the mean descriptor of every
    5th tracked frame."""
    from ..nets.dlib_resnet import face_descriptor

    n = len(ours)
    if cache is not None and cache.is_file():
        with np.load(cache) as z:
            if z["points"].shape[0] == n:
                return {"points": z["points"], "ref": z["ref"] if z["ref"].size else None}
    pts = np.full((n, 68, 2), np.nan)
    for r in ours:
        i = r["index"]
        if found[i]:
            q, _ = _frame_measures(r["driver"], descriptor=False)
            if q is not None:
                pts[i] = q
    desc = [face_descriptor(r["driver"], p68[r["index"]]) for r in ours[::5] if found[r["index"]]]
    ref = np.mean(desc, axis=0) if desc else None
    if cache is not None:
        from ..io import atomic_path

        cache.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(cache) as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, points=pts, ref=np.zeros(0) if ref is None else ref)
    return {"points": pts, "ref": ref}


def _median(a) -> float:
    a = np.asarray(a, float)
    return float(np.nanmedian(a)) if np.isfinite(a).any() else float("nan")


def _evaluate_clip(clip: Path, persona, ref_desc, out: Path, *, size, max_frames, params, write_media: bool,
                   progress: Callable | None, name: str = "", cache: Path | None = None) -> dict:
    """One run: ``persona`` driven by ``clip``; its row of measures (module docstring) and media."""
    from ..io import write_image, write_video
    from ..puppet.composite import boundary_color_step
    from ..puppet.driver import mouth_opening
    from ..puppet import neutral_texture, prepare_puppetry, render_frames

    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    session = prepare_puppetry(clip, persona, max_frames=max_frames, params=params)
    t_prep = time.perf_counter() - t0
    t0 = time.perf_counter()
    ours = list(render_frames(session, size=size, mode="composite", keep=True))
    t_render = time.perf_counter() - t0
    n = len(ours)
    track, pup = session.track, session.puppeteer
    scale = ours[0]["puppet"].shape[1] / track.frame_size[0]
    found = track.found[:n]
    p68 = (session.motion.points68 + 0.5) * scale - 0.5  # the driver's tracked landmarks, panel px
    iod = np.linalg.norm(p68[:, 36] - p68[:, 45], axis=1)
    drv = _driver_measures(clip, ours, found, p68, cache)
    drv_pts, drv_ref = drv["points"], drv["ref"]
    drv_open, drv_ear = mouth_opening(drv_pts), eye_aspect_ratio(drv_pts)
    speed = np.r_[np.nan, np.linalg.norm(np.diff(p68, axis=0), axis=2).mean(axis=1) / iod[1:]]
    speed[~found] = np.nan
    speed[1:][~found[:-1]] = np.nan
    still = np.isfinite(speed) & (speed <= np.nanpercentile(speed, 33)) if np.isfinite(speed).any() else \
        np.zeros(n, bool)
    id_frames = set(np.flatnonzero(found)[::ID_STEP].tolist())
    pup_pts = np.full((n, 68, 2), np.nan)
    d_pup, d_drv = np.full(n, np.nan), np.full(n, np.nan)
    step_c, step_d = np.full(n, np.nan), np.full(n, np.nan)
    de, sharp, eye_sharp = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    for r in ours:
        i = r["index"]
        if r["lost"]:
            continue
        pts, desc = _frame_measures(r["puppet"], descriptor=i in id_frames)
        if pts is not None:
            pup_pts[i] = pts
            if desc is not None:
                d_pup[i] = np.linalg.norm(desc - ref_desc)
                if drv_ref is not None:
                    d_drv[i] = np.linalg.norm(desc - drv_ref)
        shown = r["alpha"] > ALPHA_PUPPET
        shape = r["puppet"].shape
        de[i] = cheek_delta_e(r["puppet"], r["driver"], cheek_mask(p68[i], shape) & shown)
        sharp[i] = sharpness_ratio(r["puppet"], r["driver"], face_skin_mask(p68[i], shape) & shown)
        eye_sharp[i] = sharpness_ratio(r["puppet"], r["driver"], eye_mask(p68[i], shape) & shown)
        mask = r["alpha"] > 0.5
        if mask.sum() > 16:
            band = max(2.0, 0.05 * iod[i])
            step_c[i] = boundary_color_step(r["puppet"], mask, band=band)[0]
            step_d[i] = boundary_color_step(r["driver"], mask, band=band)[0]
        if progress:
            progress(n=1, clip=clip.stem)
    pup_open, pup_ear = mouth_opening(pup_pts), eye_aspect_ratio(pup_pts)
    # "doing nothing": the same mask and feather, no lighting/colour transfer, no Poisson blending
    from dataclasses import replace

    saved = pup.params
    pasted = replace(saved, composite=replace(saved.composite, lighting="none", poisson=False))
    paste_c, paste_d = [], []
    try:
        pup.params = pasted
        for r in ours[::5]:
            if r["lost"]:
                continue
            i = r["index"]
            img, alpha = pup.render(i, r["grid"], r["texture"], r["driver"], scale)
            mask = alpha > 0.5
            if mask.sum() > 16:
                band = max(2.0, 0.05 * iod[i])
                paste_c.append(boundary_color_step(img, mask, band=band)[0])
                paste_d.append(boundary_color_step(r["driver"], mask, band=band)[0])
    finally:
        pup.params = saved
    # expression texture against the static average, mouth region, open-mouth frames
    static = neutral_texture(persona, persona.mean_fiducials, method="static", params=params.texture_params())
    mouth = _face_region_mask(persona)
    ok = np.isfinite(drv_open)
    open_frames = np.flatnonzero(ok & (drv_open >= np.nanpercentile(drv_open, 75))) if ok.any() else []
    tex_open = float(np.mean([255 * np.abs(ours[i]["texture"] - static)[mouth].mean() for i in open_frames])) \
        if len(open_frames) else float("nan")
    sampled = np.array(sorted(id_frames), int)
    closer = (np.nan_to_num(d_pup[sampled], nan=9.0) < np.nan_to_num(d_drv[sampled], nan=0.0)) if sampled.size \
        else np.zeros(0, bool)
    row = {
        "run": f"{name}/{clip.stem}" if name else clip.stem,
        "persona": name,
        "clip": clip.stem,
        "frames": n,
        "lost": int((~found).sum()),
        "lost_causes": track.lost_causes,
        "cheek_de": _median(de),
        "sharp": _median(sharp),
        "eye_sharp": _median(eye_sharp),
        "id_closer": float(closer.mean()) if closer.size else float("nan"),
        "mouth_detected": float(np.isfinite(pup_open[found]).mean()) if found.any() else float("nan"),
        "step_ratio": float(np.nanmean(step_c) / np.nanmean(step_d)) if np.isfinite(step_d).any() else float("nan"),
        "step_puppet": float(np.nanmean(step_c)) if np.isfinite(step_c).any() else float("nan"),
        "step_driver": float(np.nanmean(step_d)) if np.isfinite(step_d).any() else float("nan"),
        "step_ratio_paste": float(np.nanmean(paste_c) / np.nanmean(paste_d)) if paste_d else float("nan"),
        "tex_open": tex_open,
        "id_puppet": float(np.nanmean(d_pup)) if np.isfinite(d_pup).any() else float("nan"),
        "id_frac": float(np.mean(np.nan_to_num(d_pup[sampled], nan=9.0) < ID_THRESHOLD)) if sampled.size
        else 0.0,
        "id_driver": float(np.nanmean(d_drv)) if np.isfinite(d_drv).any() else float("nan"),
        "id_frames": int(sampled.size),
        "flicker": _flicker([r["puppet"] for r in ours], [r["alpha"] for r in ours], still),
        "fps": n / t_render,
        "prepare_s": t_prep,
        "still_frames": int(still.sum()),
        "timings": dict(session.timings),
        "driver_opening": drv_open.tolist(),
        "puppet_opening": pup_open.tolist(),
        "driver_ear": drv_ear.tolist(),
        "puppet_ear": pup_ear.tolist(),
        "cheek_de_frames": de.tolist(),
        "sharp_frames": sharp.tolist(),
        "shape": pup.shape_source,
    }
    _series_measures(row)
    media = {}
    # contact sheet: 8 frames evenly spaced, with the most closed, widest-open and middle mouth frames
    three = sheet_frames(np.where(found, drv_open, np.nan))
    idx = np.unique(np.r_[np.linspace(0, n - 1, 8 - 3).round().astype(int), three])
    faces = {}
    for i in idx:
        r = ours[i]
        faces[i] = r["driver"] * 0 + np.asarray(pup.params.plain, np.float32) if r["lost"] else \
            pup.render(i, r["grid"], r["texture"], r["driver"], scale, "face")[0]
    if found.any():
        y0, y1, x0, x1 = _crop_box(np.nanmean(p68[found], axis=0), ours[0]["puppet"].shape)
    else:
        y0, y1, x0, x1 = 0, ours[0]["puppet"].shape[0], 0, ours[0]["puppet"].shape[1]
    rows = [[ours[i]["driver"][y0:y1, x0:x1] for i in idx], [ours[i]["puppet"][y0:y1, x0:x1] for i in idx],
            [faces[i][y0:y1, x0:x1] for i in idx]]
    labels = [[f"#{i} open {drv_open[i]:.2f}" if np.isfinite(drv_open[i]) else f"#{i}" for i in idx],
              [("LOST" if ours[i]["lost"] else f"open {pup_open[i]:.2f}" if np.isfinite(pup_open[i]) else "no face")
               for i in idx],
              ["face mode" if k == 0 else None for k in range(len(idx))]]
    sheet = out / f"{clip.stem}_contact_sheet.png"
    write_image(sheet, image_grid(rows, cell=200, cell_labels=labels, col_titles=[f"frame {i}" for i in idx]),
                overwrite=True)
    full = np.concatenate([np.concatenate([ours[i]["driver"], ours[i]["puppet"], faces[i]], axis=1) for i in idx], 0)
    sheet100 = out / f"{clip.stem}_sheet_100.png"
    write_image(sheet100, full, overwrite=True)
    # closed | widest | middle, each row driver | composite | face mode, at 100 %
    sheet3 = out / f"{clip.stem}_sheet3_100.png"
    write_image(sheet3, np.concatenate([np.concatenate([ours[i]["driver"], ours[i]["puppet"], faces[i]], axis=1)
                                        for i in three], 0), overwrite=True)
    row["sheet_frames"] = [int(i) for i in three]
    media.update(contact_sheet=str(sheet), sheet_100=str(sheet100), sheet3_100=str(sheet3))
    j = three[1]
    if ok.any() and found[j]:
        import cv2

        tiles = []
        for reg, (a, b, c, d) in _zoom_regions(p68[j], ours[j]["puppet"].shape).items():
            pair = np.concatenate([ours[j]["driver"][a:b, c:d], ours[j]["puppet"][a:b, c:d]], axis=1)
            tiles.append(cv2.resize(pair, None, fx=4, fy=4, interpolation=cv2.INTER_NEAREST))
        hmax = max(t.shape[0] for t in tiles)
        tiles = [np.pad(t, ((0, hmax - t.shape[0]), (0, 4), (0, 0)), constant_values=1.0) for t in tiles]
        zoom = out / f"{clip.stem}_zoom_frame{j}.png"
        write_image(zoom, np.concatenate(tiles, axis=1), overwrite=True)
        media["zoom"] = str(zoom)
    if write_media:
        mp4 = out / f"{clip.stem}_side_by_side.mp4"
        write_video(mp4, (np.concatenate([r["driver"], r["puppet"]], axis=1) for r in ours), track.fps,
                    audio_from=clip if track.has_audio else None, overwrite=True)
        media["mp4"] = str(mp4)
    row["media"] = media
    return row


def shifted_clip(src, dst, *, start: float = 1 / 3, end: float = 2 / 3, shift: float = 0.5,
                 max_frames: int | None = None) -> np.ndarray:
    """Write ``dst``: the clip ``src`` slid sideways out of its frame (by 0 up to the frame ``start``
    fraction, growing linearly to ``shift`` x the width at ``end``, held after it; the frame's
    edge column fills the uncovered part). Returns the per-frame shift in px (negative: left)."""
    import cv2

    from ..io import iter_video_frames, video_info, write_video

    info = video_info(src)
    frames = list(iter_video_frames(src, max_frames=max_frames))
    n = len(frames)
    h, w = frames[0].shape[:2]
    t = np.clip((np.arange(n) / max(n - 1, 1) - start) / max(end - start, 1e-9), 0, 1)
    dx = -t * shift * w
    out = [cv2.warpAffine(f, np.float32([[1, 0, d], [0, 1, 0]]), (w, h), borderMode=cv2.BORDER_REPLICATE)
           for f, d in zip(frames, dx)]
    write_video(dst, out, info["fps"] or 25.0, overwrite=True)
    return dx


def _partial_check(clip: Path, out: Path, max_frames) -> dict:
    """Rejection of half-out-of-frame faces: the clip slid out of its frame (:func:`shifted_clip`);
    ground truth from the unshifted clip's landmarks moved with the frame."""
    from ..puppet.driver import track_driver

    ref = track_driver(clip, max_frames=max_frames)
    moved = out / f"partial_{clip.stem}.mp4"
    dx = shifted_clip(clip, moved, max_frames=max_frames)
    tr = track_driver(moved, max_frames=max_frames)
    W = ref.frame_size[0]
    n = min(len(dx), tr.n_frames, ref.n_frames)
    outside = np.full(n, np.nan)
    for i in range(n):
        if ref.found[i]:
            x = ref.points68[i, :, 0] + dx[i]
            lo, hi = x.min(), x.max()
            outside[i] = (max(0.0, -0.5 - lo) + max(0.0, hi - (W - 0.5))) / max(hi - lo, 1e-9)
    partial = np.isfinite(outside) & (outside >= PARTIAL_OUTSIDE)
    whole = np.isfinite(outside) & (outside == 0)
    return {
        "clip": moved.name,
        "partial_frames": int(partial.sum()),
        "partial_rejected": int((partial & ~tr.found[:n]).sum()),
        "whole_frames": int(whole.sum()),
        "whole_kept": int((whole & tr.found[:n]).sum()),
        "lost_causes": tr.lost_causes,
    }


def _persona_file(puppet, out: Path, progress) -> str:
    """A .persona file for ``puppet``: itself, or the photo folder's persona built once and cached in ``out``."""
    from ..persona import build_persona
    from ..persona.collection import _read_header

    p = Path(puppet)
    if p.is_file():
        _read_header(p)  # not a persona: one line naming it, before any work
        return str(p)
    if not p.is_dir():
        raise BadInputError("puppet not found: give a .persona file or a photo folder", path=p)
    cached = out / f"{p.name}.persona"
    if cached.is_file():
        header, _, _ = _read_header(cached)
        if Path(header.get("source", "")).resolve() == p.resolve():
            return str(cached)
    build_persona(p, jobs=1, progress=progress).save(cached, overwrite=True)
    return str(cached)


def _data_paths(data, drivers, puppets) -> tuple[Path, list[Path]]:
    """(driver clips, puppets): the given ones, else ``DATA/grid`` and every folder of ``DATA/lfw``."""
    if isinstance(puppets, (str, os.PathLike)):
        puppets = [puppets]
    root = data or os.environ.get("FACETEX_DATA")
    if drivers is None or not puppets:
        if not root:
            raise BadInputError("no data: give --data DIR (with grid/ and lfw/<person>/), set FACETEX_DATA, "
                                "or give --drivers and --puppets")
        root = Path(root)
        drivers = root / "grid" if drivers is None else drivers
        if not puppets:
            lfw = root / "lfw"
            puppets = sorted(d for d in lfw.iterdir() if d.is_dir()) if lfw.is_dir() else []
            if not puppets:
                raise BadInputError("no photo collections (lfw/<person>/) in the data folder: give --puppets",
                                    path=lfw)
    return Path(drivers), [Path(p) for p in puppets]


def _persona_names(files: Sequence[str]) -> list[str]:
    """Short unique names of the persona files (their stems, numbered when two are the same)."""
    stems = [Path(f).stem for f in files]
    return [s if stems.count(s) == 1 else f"{s}-{k}" for k, s in enumerate(stems)]


_WORKER_CACHE: dict = {}  # persona file -> persona, per worker process (the items are persona-major)


def _bench_item(p: dict):
    """One item of the benchmark in a worker (``engine``): a persona's identity reference, a
    run's evaluation or the partial-face check; the persona is loaded once per worker."""
    from ..persona import load_persona
    from ..puppet.puppetry import PuppetParams

    if p["kind"] == "partial":
        return _partial_check(Path(p["clip"]), Path(p["out"]), p["max_frames"])
    if p["kind"] == "reference":
        return _collection_descriptor(p["persona_file"]).tolist()
    if p["persona_file"] not in _WORKER_CACHE:
        _WORKER_CACHE.clear()
        _WORKER_CACHE[p["persona_file"]] = load_persona(p["persona_file"])
    persona = _WORKER_CACHE[p["persona_file"]]
    try:
        row = _evaluate_clip(Path(p["clip"]), persona, np.asarray(p["reference"]), Path(p["out"]) / p["name"],
                             size=p["size"], max_frames=p["max_frames"],
                             params=PuppetParams(shape=p["shape"], weights=p["weights"],
                                                 weight_smoothing=p["weight_smoothing"]),
                             write_media=p["write_media"], progress=None, name=p["name"],
                             cache=Path(p["out"]) / "_cache" / f"driver_{Path(p['clip']).stem}_{p['size']}_"
                                                               f"{p['max_frames']}.npz")
    except Exception as e:  # noqa: BLE001 - one failed run is a row of the table, not the end of the bench
        row = {"run": f"{p['name']}/{Path(p['clip']).stem}", "persona": p["name"], "clip": Path(p["clip"]).stem,
               "error": f"{type(e).__name__}: {e}", "frames": 0, "lost": 0}
        row["score"], row["failed"] = run_score(row), failed_targets(row)
    row["settings"] = p["settings"]
    if p.get("store"):
        ResultStore(p["store"]).put(p["key"], json_safe(row))
    return row


def run_bench_puppet(drivers=None, puppet=None, out="bench_out/puppet", *, puppets=None, data=None,
                     clips: int | None = None, size: int | None = 256, max_frames: int | None = None,
                     texture_shape: str = "collection", weights: str = "regional",
                     weight_smoothing: float | None = None, partial: bool = True, resume: bool = False,
                     progress: Callable | None = None, engine=None) -> dict:
    """Run the puppetry benchmark: every ``*.mpg`` / ``*.mp4`` in ``drivers`` (the first ``clips``)
    drives every persona of ``puppets`` (``puppet``: one or a list; .persona files, or photo
    folders built once and cached in ``out``); ``data`` (or FACETEX_DATA) supplies the defaults
    ``grid/`` and every folder of ``lfw/``. Writes table.md, table.csv, results.json, per run a
    contact sheet, 100 % sheets and zoomed crops (in ``out/<persona>/``), for the first run a
    side-by-side MP4, and the three worst runs' 100 % sheets (module docstring).
    ``resume``: reuse the runs already stored in ``out/runs`` with the same settings.
    ``engine`` (:mod:`facetex.batch.engines`, started): the runs (and the partial-face check)
    run as its items, in parallel; default: one after another in this process.
    Returns {"out", "rows", "summary", "worst", "worst_runs", "partial", "files", "targets_met"}."""
    from dataclasses import replace

    import hashlib

    from ..io import atomic_path
    from ..puppet.puppetry import PuppetParams

    drivers, puppet_paths = _data_paths(data, drivers, puppets if puppets is not None else puppet)
    if not drivers.exists():
        raise BadInputError("driver clips not found", path=drivers)
    files = sorted(f for f in drivers.iterdir() if f.suffix.lower() in (".mpg", ".mp4", ".mov", ".avi", ".mkv")) \
        if drivers.is_dir() else [drivers]
    if not files:
        raise BadInputError("no driver videos (.mpg/.mp4/.mov/.avi/.mkv) found", path=drivers)
    if clips is not None and clips < 1:
        raise BadInputError(f"--clips must be at least 1, got {clips}")
    files = files[: clips or None]
    for p in puppet_paths:
        if not p.exists():
            raise BadInputError("puppet not found: give .persona files or photo folders", path=p)
    params = PuppetParams(shape=texture_shape, weights=weights)
    if weight_smoothing is not None:
        params = replace(params, weight_smoothing=float(weight_smoothing))
    params.texture_params()  # unknown weights, negative smoothing: an error before any work
    out = check_out_dir(out)
    persona_files = [_persona_file(p, out, progress) for p in puppet_paths]
    names = _persona_names(persona_files)
    from ..batch.engines import InlineEngine

    inline = engine is None or isinstance(engine, InlineEngine)

    def run_items(items, done=None):
        if inline:
            res = []
            for k, it in enumerate(items):
                res.append(_bench_item(it))
                if done:
                    done(index=k, result=res[-1])
            return res
        from ..batch import map_items

        return map_items(engine, _bench_item, items, progress=done)

    # the identity references (~40 descriptors each), cached per persona file (path, size, time)
    ref_cache = []
    for f in persona_files:
        st = os.stat(f)
        tag = hashlib.sha256(f"{Path(f).resolve()}\0{st.st_size}\0{st.st_mtime_ns}\0{ID_PHOTOS}".encode()).hexdigest()
        ref_cache.append(out / "_cache" / f"reference_{Path(f).stem}_{tag[:12]}.npy")
    missing = [k for k, c in enumerate(ref_cache) if not c.is_file()]
    new = run_items([{"kind": "reference", "persona_file": str(Path(persona_files[k]).resolve())} for k in missing])
    for k, d in zip(missing, new):
        ref_cache[k].parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(ref_cache[k]) as tmp:
            with open(tmp, "wb") as fh:
                np.save(fh, np.asarray(d, np.float64))
    refs = [np.load(c).tolist() for c in ref_cache]
    store = ResultStore(out / "runs")
    items, rows, todo = [], [], []
    for pf, name, ref in zip(persona_files, names, refs):
        st = os.stat(pf)
        for c in files:
            settings = {"persona_file": str(Path(pf).resolve()), "persona_bytes": st.st_size,
                        "persona_mtime": st.st_mtime, "clip": str(c.resolve()), "size": size,
                        "max_frames": max_frames, "shape": texture_shape, "weights": weights,
                        "weight_smoothing": params.weight_smoothing}
            key = ResultStore.key(name, c.stem)
            old = store.get(key) if resume else None
            if old is not None and old.get("settings") == json_safe(settings):
                rows.append(old)
                continue
            rows.append(None)
            todo.append(len(rows) - 1)
            items.append({"kind": "clip", "clip": str(c), "persona_file": settings["persona_file"], "name": name,
                          "reference": list(ref), "out": str(out.resolve()), "size": size,
                          "max_frames": max_frames, "shape": texture_shape, "weights": weights,
                          "weight_smoothing": params.weight_smoothing, "write_media": len(rows) == 1,
                          "settings": settings, "store": str(store.folder), "key": key})
    if partial:
        items.append({"kind": "partial", "clip": str(files[0]), "out": str(out.resolve()), "max_frames": max_frames})

    def done(n=1, index=0, result=None):
        if progress and items[index]["kind"] == "clip":
            progress(n=int(result.get("frames", 1)), clip=Path(items[index]["clip"]).name)

    results = run_items(items, done)
    for k, r in zip(todo, results):
        rows[k] = r
    part = results[len(todo)] if partial else None
    return _write_tables(out, rows, part, drivers=drivers, files=files, persona_files=persona_files,
                         puppet_paths=puppet_paths, size=size, weights=weights, params=params, max_frames=max_frames)


def _write_tables(out: Path, rows: list, part, *, drivers, files, persona_files, puppet_paths, size, weights,
                  params, max_frames) -> dict:
    """table.md, table.csv, results.json and the worst runs' sheets of a finished bench."""
    from ..io import read_image, write_json

    rows = [_series_measures(dict(r)) for r in rows]
    keys = [c.key for c in COLUMNS[2:]]
    summary = {"persona": "mean", "clip": ""}
    worst = {"persona": "worst", "clip": ""}
    worst_run = {}
    for k in keys:
        vals = [r.get(k) for r in rows]
        fin = [v for v in vals if isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)]
        summary[k] = float(np.mean(fin)) if fin else float("nan")
        worst[k] = _worst_value(k, vals)
        if np.isfinite(worst[k]):
            worst_run[k] = next((r["run"] for r in rows if r.get(k) == worst[k]), None)
    summary["frames"], summary["lost"] = int(sum(r.get("frames", 0) for r in rows)), \
        int(sum(r.get("lost", 0) for r in rows))
    bad = worst_runs(rows)
    n_fail = {k: sum(_shortfall(k, r.get(k)) > 0 for r in rows) for k in TARGETS}
    head = (f"# Puppetry benchmark\n\n{len(persona_files)} persona(s) × {len(files)} clip(s) from `{drivers}` = "
            f"{len(rows)} runs; panel size {size or 'native'}; texture weights: {weights}; weight smoothing: "
            f"{params.weight_smoothing:g} s. Personas: " +
            ", ".join(f"`{Path(f).name}`" for f in persona_files) + ".\n\n"
            "Targets per run (issue 21): mouth slope 0.8–1.3 and r >= 0.85; cheek ΔE to the driver <= 8 (CIELAB, "
            "composite); eye openness >= 0.8 of the driver's; face sharpness >= 0.75 of the driver's; composite "
            "closer to the persona than to the driver (dlib descriptor) on >= 80 % of sampled frames. "
            "Fail score: failed targets + their relative shortfalls (0 = all met).\n\n")
    worst_md = ["", "## Worst run per measure", "", "| measure | target | worst | run | runs failing |",
                "|---|---|---:|---|---:|"]
    titles = {c.key: c for c in COLUMNS}
    for k, (lo, hi) in TARGETS.items():
        tgt = f"{lo:g}–{hi:g}" if lo is not None and hi is not None else f">= {lo:g}" if lo is not None else \
            f"<= {hi:g}"
        worst_md.append(f"| {titles[k].title} | {tgt} | {titles[k].format(worst[k])} | {worst_run.get(k) or '–'} | "
                        f"{n_fail[k]}/{len(rows)} |")
    worst_md += ["", f"## The {len(bad)} worst runs (by fail score)", ""]
    sheets = {}
    for rank, i in enumerate(bad, 1):
        r = rows[i]
        src = (r.get("media") or {}).get("sheet3_100")
        line = f"{rank}. `{r['run']}`: score {r['score']:.2f}, failed: {', '.join(r.get('failed') or []) or '–'}"
        if r.get("error"):
            line += f"; error: {r['error']}"
        if src and Path(src).is_file():
            dst = out / f"worst{rank}_{ResultStore.key(r['persona'], r['clip'])}.png"
            _write_worst_sheet(dst, read_image(src), r)
            sheets[f"worst{rank}"] = dst
            line += f"; sheet `{dst.name}` (rows: driver's most closed, widest-open, middle mouth frames " \
                    f"{r.get('sheet_frames')}; columns: driver | composite | face mode; 100 %)"
        worst_md.append(line)
    table_rows = rows + [summary, worst]
    ok = {k: n_fail[k] == 0 for k in TARGETS}
    ok["boundary"] = bool(rows) and all(np.isfinite(r.get("step_ratio", np.nan))
                                        and r["step_ratio"] <= STEP_RATIO_TARGET for r in rows)
    tail = "\n" + "\n".join(worst_md) + "\n\n" + "; ".join(f"{k} target met: {v}" for k, v in ok.items()) + "\n"
    errs = [r for r in rows if r.get("error")]
    if errs:
        tail += "\nFailed runs: " + "; ".join(f"{r['run']}: {r['error']}" for r in errs) + "\n"
    lost = {r["run"]: r["lost_causes"] for r in rows if r.get("lost")}
    if lost:
        tail += "\nLost frames by cause: " + "; ".join(f"{c}: {v}" for c, v in lost.items()) + "\n"
    if part is not None:
        ok["partial"] = (part["partial_rejected"] == part["partial_frames"]
                         and part["whole_kept"] == part["whole_frames"])
        tail += (f"\nPartial faces (`{part['clip']}`, the first clip slid out of its frame): "
                 f"{part['partial_rejected']}/{part['partial_frames']} frames with >= {PARTIAL_OUTSIDE:.0%} of the "
                 f"face outside rejected, {part['whole_kept']}/{part['whole_frames']} whole-face frames kept "
                 f"(causes: {part['lost_causes']}); target met: {ok['partial']}\n")
    paths = {"table_md": out / "table.md", "table_csv": out / "table.csv", "results": out / "results.json"}
    write_text(paths["table_md"], head + markdown_table(COLUMNS, table_rows) + tail)
    write_text(paths["table_csv"], csv_table(COLUMNS, table_rows))
    worst_list = [{"run": rows[i]["run"], "score": rows[i]["score"], "failed": rows[i].get("failed"),
                   "sheet": str(sheets.get(f"worst{k}", ""))} for k, i in enumerate(bad, 1)]
    write_json(paths["results"], json_safe({
        "bench": "puppet",
        "settings": {"drivers": str(drivers), "puppets": [str(p) for p in puppet_paths],
                     "persona_files": persona_files, "size": size, "weights": weights, "max_frames": max_frames,
                     "targets": {k: list(v) for k, v in TARGETS.items()}, "versions": versions()},
        "rows": rows, "summary": summary, "worst": {**worst, "runs": worst_run}, "worst_runs": worst_list,
        "partial": part, "targets_met": ok}), overwrite=True)
    paths.update(sheets)
    if rows and rows[0].get("media"):
        paths.update({k: Path(v) for k, v in rows[0]["media"].items()})
    return {"out": out, "rows": rows, "summary": summary, "worst": worst, "worst_runs": worst_list, "partial": part,
            "files": paths, "targets_met": ok}


def _write_worst_sheet(path: Path, sheet: np.ndarray, row) -> None:
    """The run's 100 % sheet under a white band naming the run, its score and failed measures."""
    import cv2

    from ..io import to_uint8, write_image

    img = to_uint8(sheet)
    band = np.full((22, img.shape[1], 3), 255, np.uint8)
    vals = ", ".join(f"{k} {row.get(k):.2f}" for k in TARGETS if isinstance(row.get(k), (int, float))
                     and np.isfinite(row.get(k)))
    cv2.putText(band, f"{row['run']}  score {row['score']:.2f}  {vals}", (4, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.38,
                (0, 0, 0), 1, cv2.LINE_AA)
    write_image(path, np.concatenate([band, img], 0), overwrite=True)


# --------------------------------------------------------------------------- CLI
def register_bench(bench_subparsers) -> argparse.ArgumentParser:
    """Add the ``puppet`` sub-parser to ``facetex bench``."""
    from ..cli._common import bounded_int, finite_float, positive_int
    from ._common import add_bench_options

    p = bench_subparsers.add_parser(
        "puppet", help="puppetry: every persona x every driver clip (mouth, colour, eyes, sharpness, identity)",
        description="Driver clips drive personas (Tom Hanks §4, §6), every persona with every clip; measured per "
                    "run: the mouth (slope and correlation of the puppet's opening on the driver's), the cheek "
                    "colour (ΔE to the driver's own cheeks), eye openness and blinks, face sharpness, identity "
                    "(closer to the persona than to the driver), the colour step at the composite's edge, lost "
                    "and rejected frames (with a half-out-of-frame check) and flicker. Writes table.md/.csv "
                    "with the worst run of every measure, results.json, per run contact sheets (fitted and "
                    "at 100 %) and zoomed crops, and the 100 % sheets of the three worst runs.")
    add_bench_options(p, "puppet", "data root holding grid/ (driver clips) and lfw/<person>/ (the puppets)")
    p.add_argument("--drivers", metavar="DIR", help="folder of driver videos (default DATA/grid)")
    p.add_argument("--puppets", "--puppet", nargs="+", metavar="PATH", dest="puppets",
                   help="puppet .persona files or photo folders (default every folder of DATA/lfw; a folder is "
                        "built once and cached in --out)")
    p.add_argument("--clips", type=positive_int, help="use only the first N clips")
    p.add_argument("--size", type=bounded_int(32, 4096), default=256, help="longer side of the rendered frames (default 256)")
    p.add_argument("--max-frames", type=positive_int, help="use only the first N frames of each clip")
    p.add_argument("--shape", choices=("collection", "generic"), default="collection",
                   help="puppet average shape: photometric stereo (falls back to generic) or the generic face")
    p.add_argument("--weights", choices=("regional", "global"), default="regional",
                   help="expression weights of the puppet's texture: regional (default) or the paper's global")
    p.add_argument("--weight-smoothing", type=finite_float(0.0, 10.0), metavar="SECONDS",
                   help="temporal coherence of the regional weights (bilateral filter over this many seconds; "
                        "0 = per frame; default: the puppet's default)")
    p.add_argument("--no-partial", action="store_true", help="skip the half-out-of-frame check")
    p.add_argument("--resume", action="store_true",
                   help="reuse the runs already in OUT/runs with the same settings (persona file, clip, options)")
    from ..cli._common import add_engine_options

    add_engine_options(p, jobs_help="local: worker processes, one run each (default: the available CPUs); ray: "
                                    "runs in flight")
    p.set_defaults(func=_run)
    return p


def _run(args) -> int:
    from ..cli._common import progress_bar
    from ..io import video_info
    from ._common import data_root, finish_bench

    root = None if (args.drivers and args.puppets and not args.data) else data_root(args.data)
    drivers, puppets = _data_paths(root, args.drivers, args.puppets)
    clips = sorted(f for f in drivers.iterdir() if f.suffix.lower() in (".mpg", ".mp4", ".mov", ".avi", ".mkv")) \
        if drivers.is_dir() else [drivers]
    clips = clips[: args.clips or None]
    total = 0
    for c in clips:  # the bar counts evaluated frames
        try:
            n = video_info(c)["n_frames"]
        except Exception:  # noqa: BLE001 - the run itself reports a bad clip
            n = 0
        total += min(n, args.max_frames) if args.max_frames else n
    total *= len(puppets)
    from ..cli._common import engine_from_args

    with engine_from_args(args, inline_single=True) as engine, \
            progress_bar(total=total or None, desc="bench puppet", unit="frame", disable=args.quiet) as bar:
        res = run_bench_puppet(drivers, puppets=puppets, out=args.out, clips=args.clips, size=args.size,
                               max_frames=args.max_frames, texture_shape=args.shape, weights=args.weights,
                               weight_smoothing=args.weight_smoothing, partial=not args.no_partial,
                               resume=args.resume, progress=bar, engine=engine)
    table = Path(res["files"]["table_md"]).read_text(encoding="utf-8")
    finish_bench(args, "puppet", res["out"], res["files"],
                 inputs={"drivers": drivers, **{f"puppet{k}": p for k, p in enumerate(puppets)}},
                 settings={"drivers": str(drivers), "puppets": [str(p) for p in puppets]},
                 summary={"summary": res["summary"], "worst": res["worst"], "worst_runs": res["worst_runs"],
                          "partial": res["partial"], "targets_met": res["targets_met"]},
                 table=table)
    return 0


def run_bench_puppet_cli(argv: Sequence[str] | None = None) -> int:
    """Stand-alone entry (``python -m facetex.bench.puppet``)."""
    ap = argparse.ArgumentParser(prog="facetex bench")
    register_bench(ap.add_subparsers(dest="bench", required=True))
    args = ap.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    raise SystemExit(run_bench_puppet_cli())
