"""Eyeglasses in a face photo, from the frame's bridge over the nose; their rims in a video.

Hand-written (no package on the registry ships an eyeglasses detector that runs here): the
bridge of a pair of glasses crosses the nose between the inner eye corners as a horizontal
line, where bare skin changes slowly from top to bottom. The score is the strongest row of
vertical gradient across that box over the box's mean horizontal gradient. It separates the
glasses photos of the shared LFW collections from the rest only *relative to the person's
own photos* (skin tone, lighting and the nose's shading set its level), so
:func:`glasses_weights` compares each photo with its collection's median.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..io import LUMA_BT601
from ..landmarks import eye_distance
from .masks import disc

__all__ = ["glasses_bridge_score", "glasses_weights", "rim_response", "rim_template", "rim_scores", "rims_present",
           "rim_mask"]


def luminance_and_points(image, points68) -> tuple[np.ndarray, np.ndarray | None]:
    """(luminance (H, W) float32 in [0, 1] of ``image`` (uint8 or float [0, 1], RGB(A)), its iBUG-68
    points as float64 (68, 2) or None when they are not 68 finite points): what the per-photo
    eye-region scores (bridge, gaze) start from."""
    img = np.asarray(image)
    lum = img[..., :3].astype(np.float32) @ LUMA_BT601
    if img.dtype == np.uint8:
        lum /= 255.0
    p = np.asarray(points68, np.float64)
    return lum, (p if p.shape == (68, 2) and np.isfinite(p).all() else None)


def glasses_bridge_score(image, points68) -> float:
    """Bridge-line score of one face ``image`` (H, W, 3) (uint8 or float [0, 1]) with its iBUG-68
    ``points68`` (68, 2): max over the rows of the box between the inner eye corners (middle 60 %
    of their distance; from 0.3 eye-centre distances above their line to 0.1 below) of the row's
    mean |d/dy| of the luminance (Gaussian sigma 1 px, Sobel), over the box's mean |d/dx| (+1e-3).
    NaN when the box is empty or off the image."""
    lum, p = luminance_and_points(image, points68)
    if p is None:
        return float("nan")
    left, right = p[39], p[42]
    iod = eye_distance(p)
    y_line = (left[1] + right[1]) / 2
    dx = right[0] - left[0]
    x0, x1 = int(round(left[0] + 0.2 * dx)), int(round(right[0] - 0.2 * dx))
    y0, y1 = int(round(y_line - 0.3 * iod)), int(round(y_line + 0.1 * iod))
    h, w = lum.shape
    # a margin of 3 px for the blur and the Sobel
    if x1 - x0 < 2 or y1 - y0 < 2 or x0 < 3 or y0 < 3 or x1 > w - 3 or y1 > h - 3:
        return float("nan")
    crop = cv2.GaussianBlur(lum[y0 - 3:y1 + 3, x0 - 3:x1 + 3], (0, 0), 1.0)
    gy = np.abs(cv2.Sobel(crop, cv2.CV_32F, 0, 1, ksize=3))[3:-3, 3:-3]
    gx = np.abs(cv2.Sobel(crop, cv2.CV_32F, 1, 0, ksize=3))[3:-3, 3:-3]
    return float(gy.mean(axis=1).max() / (gx.mean() + 1e-3))


def glasses_weights(scores, *, level: float = 1.25, power: float = 4.0) -> np.ndarray:
    """(n,) weights in (0, 1] of photos by their :func:`glasses_bridge_score` ``scores`` (n,):
    1 up to ``level`` x the collection's median score, then (score / (level x median)) ** -power
    (the shared LFW collections: glasses photos 1.6-3.6 x their median, photos without 0.3-2.1
    x; a photo without glasses that scores high loses some weight, one with glasses most; at
    level 1.5 Arroyo's puppet still showed faint rims).
    NaN scores (no box) and a collection without a usable median get weight 1."""
    s = np.asarray(scores, np.float64)
    out = np.ones(s.shape)
    ok = np.isfinite(s)
    if ok.sum() < 3 or power <= 0:
        return out
    med = float(np.median(s[ok]))
    if med <= 0:
        return out
    ratio = np.where(ok, s / (level * med), 1.0)
    out = np.clip(ratio, 1.0, None) ** -power
    return out


# ----------------------------------------------------------------------------- rims in a video
#: the face frame the rims are averaged in: the middles of the eyes' corners at (50, 40) and
#: (110, 40), the nose ridge's middle (points 27-30) at (80, 52); (width, height)
RIM_FRAME = (160, 96)
_RIM_ANCHORS = np.float32([[50, 40], [110, 40], [80, 52]])
#: radius (face-frame px) of the thin lines' element: lines up to ~6 px wide there (a frame 0.1 of
#: the eye distance thick); 2 px missed 2 px rims drawn on a face 26 px between the eyes
RIM_RADIUS = 3
#: the rims' zone in that frame: rows above ``RIM_ROWS[1]`` (the lower rims end above the cheeks),
#: the bridge's columns ``RIM_BRIDGE`` only above row ``RIM_ROWS[0]`` (below it: the nose's sides)
RIM_ROWS, RIM_BRIDGE = (50, 68), (70, 91)
#: the least cheek line strength :func:`rim_scores` divides by, over the face's median luminance:
#: the mean of a still clip's frames has cheeks without lines (GRID lrwp9a 0.0003; 0.0016-0.013
#: on the other clips and copies), over which any crease would score as a rim
CHEEK_FLOOR = 0.008


def _face_similarity(points68) -> np.ndarray | None:
    """2 x 3 similarity from the frame's px into :data:`RIM_FRAME` (eye corners and nose ridge), or None."""
    p = np.asarray(points68, np.float64)
    if p.shape != (68, 2) or not np.isfinite(p).all():
        return None
    # the eyes' corners, not their lids' mean: a smile's squint moved that up and the rims with it
    src = np.float32([(p[36] + p[39]) / 2, (p[42] + p[45]) / 2, p[27:31].mean(0)])
    M, _ = cv2.estimateAffinePartial2D(src, _RIM_ANCHORS)
    return M


def _thin_lines(lum: np.ndarray, radius: int) -> np.ndarray:
    """Dark plus light thin structures of a luminance image: its black-hat plus top-hat with an
    elliptical element of ``radius`` px (rims, lashes, creases; not the slow shading)."""
    se = disc(radius)
    return cv2.morphologyEx(lum, cv2.MORPH_BLACKHAT, se) + cv2.morphologyEx(lum, cv2.MORPH_TOPHAT, se)


def rim_response(image, points68) -> np.ndarray | None:
    """One face's luminance in the face frame :data:`RIM_FRAME`: float32 (96, 160); None without
    usable landmarks. Over a video's frames (:func:`rim_template`) a pair of glasses, fixed to the
    head, stays while the codec's block edges and the noise average out."""
    lum, p = luminance_and_points(image, points68)
    M = None if p is None else _face_similarity(p)
    if M is None:
        return None
    return cv2.warpAffine(lum, M, RIM_FRAME, flags=cv2.INTER_AREA if abs(np.linalg.det(M[:, :2])) < 1 else
                          cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float32)


def rim_template(responses) -> np.ndarray | None:
    """A video's :func:`rim_response` maps (None entries skipped) as one float32 (2, 96, 160) map,
    or None when none: the thin lines (:func:`_thin_lines`, radius :data:`RIM_RADIUS`) of the
    mean luminance, and that mean. The lines of the mean, not the mean of each frame's lines: a
    line response is never negative, so a noisy frame's lines add up over the frames (a dimmed
    copy of GRID lbax4n with sensor noise: cheek lines 5x the clean clip's, and its glasses scored
    1.45, 1.61 where the clean clip scored 12.8, 13.8), while the luminance's noise averages out."""
    maps = [r for r in responses if r is not None]
    if not maps:
        return None
    mean = np.mean(maps, axis=0).astype(np.float32)
    return np.stack([_thin_lines(mean, RIM_RADIUS), mean]).astype(np.float32)


def rims_strength(lines) -> float:
    """The strongest row's mean of a template's thin lines (:func:`rim_template` [0]) across the
    nose's bridge between the eyes (the :data:`RIM_BRIDGE` columns from row 28 to :data:`RIM_ROWS` [0])."""
    (b0, b1), top = RIM_BRIDGE, RIM_ROWS[0]
    return float(np.asarray(lines, np.float32)[28:top, b0:b1].mean(axis=1).max())


def rim_scores(template) -> tuple[float, float, float]:
    """(bridge, arms, edge) of a :func:`rim_template`. Its thin lines, over the median of the cheeks
    below the eyes (at least :data:`CHEEK_FLOOR` x the face's median luminance): across the nose's
    bridge between the eyes (:func:`rims_strength`), and the weaker side's strongest row at eye level (rows 30-49) just inside the face's sides (columns
    12-25 and 134-147: the temples' arms; crow's feet fan out, a row does not hold them). And its
    mean luminance's bridge edge: the strongest row of vertical gradient across the bridge (rows
    22-46 of the middle columns 73-87) over the mean horizontal gradient there (as
    :func:`glasses_bridge_score`, in the face frame)."""
    t = np.asarray(template, np.float32)
    lines, lum = t[0], t[1]
    cheeks = max(float(np.median(np.concatenate([lines[60:80, 40:60].ravel(), lines[60:80, 100:120].ravel()]))),
                 CHEEK_FLOOR * float(np.median(lum[30:80, 30:130])), 1e-4)
    arms = min(float(lines[30:50, 12:26].mean(axis=1).max()), float(lines[30:50, 134:148].mean(axis=1).max()))
    blur = cv2.GaussianBlur(lum, (0, 0), 1.0)
    gy = np.abs(cv2.Sobel(blur, cv2.CV_32F, 0, 1, ksize=3))[22:47, 73:88]
    gx = np.abs(cv2.Sobel(blur, cv2.CV_32F, 1, 0, ksize=3))[22:47, 73:88]
    return rims_strength(lines) / cheeks, arms / cheeks, float(gy.mean(axis=1).max() / (gx.mean() + 1e-3))


def rims_present(template, *, bridge: float = 4.5, arms: float = 5.0, edge: float = 1.5) -> bool:
    """Whether a :func:`rim_template` shows a pair of glasses: its :func:`rim_scores` at least
    ``bridge``, ``arms`` and ``edge``. None alone separates them: a frown's furrows, a squint's
    creases and a nose's bridge crease each score high on one. Measured: GRID lbax4n (thin gold
    rims, 25 frames) 10.6, 9.8 and 1.78, its dimmed noisy copy (``facetex bench puppet --stress``)
    5.5, 5.4 and 1.77 (thin margins); the five other GRID clips and six altered copies (mirrored
    and side-lit, rotated 14 degrees with the face shrunk, dimmed with noise) at most 3.7, 2.9 and
    1.12. Single photos, a video's worst case (no average): of 482 in FRL London, Helen and LFW at
    GRID's size, 7 pass, 5 of them with glasses (the others a laughing squint and a turned head);
    rims drawn without arms on the bundled sample face score 4.85 arms."""
    if template is None:
        return False
    a, b, c = rim_scores(template)
    return a >= bridge and b >= arms and c >= edge


def rim_mask(image, points68, template, *, strong: float = 0.3, piece: int = 10, level: float = 0.5,
             soft: float = 0.7) -> np.ndarray:
    """float32 (H, W) in [0, 1]: a video frame's pixels on its glasses' rims, which stay in front of
    a puppet; zeros when ``template`` (:func:`rim_template` of the video) shows no glasses
    (:func:`rims_present`).

    1. The rims in the face frame: the template's thin lines over ``strong`` x its bridge's
       (:func:`rims_strength`; at 0.4 the upper rims by the brows were lost) in the rim zone
       (:data:`RIM_ROWS`, :data:`RIM_BRIDGE`, inside the jaw's sides), without the eyes, the brows
       and the nose below the bridge (the puppet's own are drawn there) and without pieces less
       than ``piece`` px across (moles).
    2. Moved into the frame, times the frame's own dark thin lines (full at ``level`` x the rims'
       median in the template): a head that turns moves the rims off the template by a pixel or
       two. Its light lines are left out: beside the rims they are the skin's highlights (the
       nose's sides by the pads drew light patches on darker puppets).
    3. Grown by a pixel and blurred (Gaussian ``soft`` px; 0: not): the rim's light side and the
       skin beside it come with it. The dark core alone drew GRID lbax4n's gold rims as hard dark
       lines (the face's Laplacian variance 1.1-1.6 x the driver's at 360 px; now 0.86-1.39)."""
    img = np.asarray(image)
    h, w = img.shape[:2]
    out = np.zeros((h, w), np.float32)
    lum, p = luminance_and_points(img, points68)
    M = None if p is None else _face_similarity(p)
    if M is None or not rims_present(template):
        return out
    t = np.asarray(template, np.float32)[0]
    zone = np.zeros(t.shape, bool)
    zone[:RIM_ROWS[1]] = True
    zone[RIM_ROWS[0]:, RIM_BRIDGE[0]:RIM_BRIDGE[1]] = False
    pf = cv2.transform(p[None].astype(np.float32), M)[0]
    cut = np.zeros(t.shape, np.uint8)
    # eyes, brows and the nose below its bridge (its sides' shading): the puppet's own are drawn there
    for idx in (range(36, 42), range(42, 48), range(17, 22), range(22, 27), range(29, 36)):
        cv2.fillPoly(cut, [cv2.convexHull(pf[list(idx)]).astype(np.int32)], 1)
    cut = cv2.dilate(cut, disc(5)) > 0
    zone &= ~cut
    # inside the face's sides (jaw points 0 and 16): beyond them the frame is not replaced
    zone[:, :max(0, int(np.ceil(pf[0, 0])))] = False
    zone[:, max(0, int(np.floor(pf[16, 0])) + 1):] = False
    rims = ((t > strong * rims_strength(t)) & zone).astype(np.uint8)
    # rims are long curves: pieces under ``piece`` px across are the frame's moles and pores
    n, lab, stats, _ = cv2.connectedComponentsWithStats(rims, connectivity=8)
    rims = np.isin(lab, 1 + np.flatnonzero(stats[1:, 2:4].max(axis=1) >= piece)).astype(np.uint8)
    strength = float(np.median(t[rims > 0])) if rims.any() else 0.0
    if strength <= 0:
        return out
    Minv = cv2.invertAffineTransform(M)
    back = cv2.warpAffine(rims.astype(np.float32), Minv, (w, h), flags=cv2.INTER_LINEAR) > 0.25
    scale = float(np.sqrt(abs(np.linalg.det(M[:, :2]))))  # face-frame px per frame px
    # at least 5 px: OpenCV's 3 x 3 ellipse is a cross, which does not close a 2 px line
    r = max(2, int(np.ceil(RIM_RADIUS / max(scale, 1e-6))))
    lines = cv2.morphologyEx(lum, cv2.MORPH_BLACKHAT, disc(r))
    core = (back * np.clip(lines / (level * strength), 0.0, 1.0)).astype(np.float32)
    if soft <= 0:
        return core
    grown = cv2.dilate(core, disc(1))
    return np.clip(cv2.GaussianBlur(grown, (0, 0), soft), 0.0, 1.0).astype(np.float32)
