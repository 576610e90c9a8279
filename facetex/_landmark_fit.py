"""dlib's 68 landmarks fitted for measuring expression: on an upscale of a small face, refitted in
the box the landmarks carry, a dark face's mouth at a normalised exposure.

dlib's detector finds the box, its shape predictor the points; on a small face (an LFW photo's or a
GRID frame's ~100 px box) the predictor reads single pixels and its points move in pixel steps. The
driver's tracker (:mod:`facetex.puppet.driver`) and the persona's build
(:func:`facetex.persona.build.process_photo`) both fit them this way (:func:`fit_landmarks`,
:func:`refine_landmarks`): a driver frame's expression and a photo's are read alike before they are
compared.
"""

from __future__ import annotations

import math

import numpy as np

from .io import LUMA_BT601, linear_to_srgb, srgb_to_linear
from .landmarks import landmarks_in_box

__all__ = ["EXPOSED_FACE_LUMA", "MIN_EXPOSURE_GAIN", "exposure_gain", "fit_landmarks", "carried_box",
           "mirror_averaged", "refit_in_carried_boxes", "refine_landmarks", "BOX_JITTERS", "jittered_landmarks"]

#: A face whose box's middle has a median sRGB luma below this gets its mouth landmarks refitted at
#: the exposure that brings it there (:func:`fit_landmarks`), when that takes a gain of at least
#: MIN_EXPOSURE_GAIN (the refit costs a second fit; a smaller gain hardly moves the points).
EXPOSED_FACE_LUMA = 0.55
MIN_EXPOSURE_GAIN = 1.05


def exposure_gain(image, box) -> float:
    """The linear-light gain (>= 1) that brings the median sRGB luma of the middle 60 % of a face
    ``box`` (x0, y0, x1, y1) in ``image`` (uint8 or float RGB) up to :data:`EXPOSED_FACE_LUMA` (1 for
    a lighter face)."""
    a = np.asarray(image)
    b = np.asarray(box, np.float64).ravel()
    h, w = a.shape[:2]
    c, half = (b[:2] + b[2:]) / 2, 0.3 * (b[2:] - b[:2])
    x0, y0 = (int(max(0, v)) for v in c - half)
    x1, y1 = int(min(w, c[0] + half[0])), int(min(h, c[1] + half[1]))
    if x1 - x0 < 4 or y1 - y0 < 4:
        return 1.0
    sub = a[y0:y1, x0:x1, :3].reshape(-1, 3).astype(np.float32)
    if a.dtype == np.uint8:
        sub /= 255.0
    luma = float(np.median(sub @ LUMA_BT601))
    return max(1.0, float(srgb_to_linear(EXPOSED_FACE_LUMA)) / max(float(srgb_to_linear(luma)), 1e-4))


def _landmarks_exposed(image, box, exposure: bool = True, mirror: bool = False, points68=None) -> np.ndarray:
    """dlib's 68 landmarks in ``box`` (or ``points68``, already fitted there), the mouth's (48-67)
    fitted again at a normalised exposure on a dark face (:func:`exposure_gain`; one gain in linear
    light, as a camera's exposure) unless ``exposure`` is False; averaged with the fit of the mirror
    image when ``mirror`` (:func:`mirror_averaged`)."""
    p = landmarks_in_box(image, box) if points68 is None else np.asarray(points68, np.float64)
    p = _mouth_exposed(image, box, p) if exposure else p
    return mirror_averaged(image, box, p, exposure) if mirror else p


def mirror_averaged(image, box, points68, exposure: bool = True) -> np.ndarray:
    """The mean of ``points68`` (fitted in ``box``) and the same fit on the image's mirror image, its
    points mapped back (left and right swapped: :data:`facetex.geometry.FLIP68`).

    dlib's regressor is not mirror-symmetric: a face and its mirror image give points ~0.5 px apart
    on an LFW face at 2x (1.3 % of the eye distance). The mean is the same for both (a flip
    commutes with it) and averages out part of the fit's own scatter. The driver's tracker mirrors
    its last fit this way (``DriverParams.landmark_mirror``); the persona's photos repeat their whole
    refinement on the mirror image (:func:`refine_landmarks`)."""
    flipped, fbox = _mirrored(image, box)
    q = landmarks_in_box(flipped, fbox)
    if exposure:
        q = _mouth_exposed(flipped, fbox, q)
    return (np.asarray(points68, np.float64) + _mirror_points(q, flipped.shape[1])) / 2


#: The box changes of :func:`jittered_landmarks`: (dx, dy, scale), the shifts in box widths.
BOX_JITTERS = ((0.0, 0.0, 1.0), (0.03, 0.0, 1.0), (-0.03, 0.0, 1.0), (0.0, 0.03, 1.0), (0.0, -0.03, 1.0),
               (0.0, 0.0, 1.03), (0.0, 0.0, 0.97))


def jittered_landmarks(image, box, *, exposure: bool = True) -> np.ndarray:
    """(68, 2) per-coordinate median of dlib's fits in ``box`` moved and scaled by each of
    :data:`BOX_JITTERS`, each averaged with the mirror image's fit in the mirrored box (a dark
    face's mouth at a normalised exposure, one gain from ``box``, unless ``exposure`` is False):
    14 fits, for measuring (each on the same uint8 crop round the box: ~0.1 s for a 1000 px frame).

    dlib's regression trees compare pixel pairs against thresholds: on a closed mouth whose upper
    lip is dark and lower lip pink (FRL London portrait 006, 1000 px) two frames of one H.264 still
    (mean difference 0.0002) read openings 0.005 and 0.051, three frames in a row 0.05. Over the
    same still holds of six 1000 px portrait clips (15 frames each) the opening's standard deviation
    fell from 0.0019-0.0118 (one fit, the mouth refitted at the exposure) to 0.0006-0.0024 (mean
    0.0048 -> 0.0013), the neutral -> smile step the same (0.055-0.118 -> 0.058-0.122). A noisy
    reading of the driver's opening flattens a slope fitted on it (regression dilution)."""
    from .landmarks import _as_uint8_rgb, _checked_box, _dlib_rect, _shape68

    b = _checked_box(box)
    a = np.asarray(image)
    h, w = a.shape[:2]
    c, half = (b[:2] + b[2:]) / 2, (b[2:] - b[:2]) / 2
    reach = 0.8 * (b[2] - b[0])  # past the largest jittered box
    x0, y0 = max(0, int(b[0] - reach)), max(0, int(b[1] - reach))
    x1, y1 = min(w, int(math.ceil(b[2] + reach))), min(h, int(math.ceil(b[3] + reach)))
    crop = a[y0:y1, x0:x1]
    shift = np.array([x0, y0], np.float64)
    views = [_as_uint8_rgb(crop)]
    g = exposure_gain(crop, b - np.tile(shift, 2)) if exposure else 1.0
    if g >= MIN_EXPOSURE_GAIN:
        views.append(_as_uint8_rgb(_exposed(views[0].astype(np.float32) / 255.0, g)))
    cw = x1 - x0
    flipped = [np.ascontiguousarray(v[:, ::-1]) for v in views]

    def fit(imgs, bb):  # the whole face on the first image, the mouth on the brightened one
        rect = _dlib_rect(bb)
        p = _shape68(imgs[0], rect)
        if len(imgs) > 1:
            p[48:68] = _shape68(imgs[1], rect)[48:68]
        return p

    fits = []
    for dx, dy, k in BOX_JITTERS:
        cc = c - shift + np.array([dx, dy]) * 2 * half[0]
        bb = np.r_[cc - k * half, cc + k * half]
        fits.append((fit(views, bb) + _mirror_points(fit(flipped, _mirror_box(bb, cw)), cw)) / 2)
    return np.median(fits, axis=0) + shift


def _mirrored(image, box) -> tuple[np.ndarray, tuple]:
    """The mirror image (contiguous) of ``image`` and ``box`` (x0, y0, x1, y1) mirrored with it."""
    a = np.asarray(image)
    w = a.shape[1]
    b = np.asarray(box, np.float64).ravel()
    return np.ascontiguousarray(a[:, ::-1]), _mirror_box(b, w)


def _mirror_box(box, width: int) -> tuple:
    """A box (x0, y0, x1, y1) of an image ``width`` px wide as it is in its mirror image."""
    return (width - 1 - box[2], box[1], width - 1 - box[0], box[3])


def _mirror_points(points68, width: int) -> np.ndarray:
    """(68, 2) landmarks of an image ``width`` px wide as they are in its mirror image (x -> width - 1
    - x, left and right points swapped: :data:`facetex.geometry.FLIP68`); its own inverse."""
    from .geometry._generic_face import FLIP68

    q = np.asarray(points68, np.float64)[FLIP68]
    q[:, 0] = width - 1 - q[:, 0]
    return q


def _exposed(image: np.ndarray, gain: float) -> np.ndarray:
    """Float sRGB ``image`` in [0, 1] brightened by ``gain`` in linear light (a camera's exposure)."""
    return linear_to_srgb(srgb_to_linear(image) * np.float32(gain))


def _mouth_exposed(image, box, p) -> np.ndarray:
    """``p`` (68, 2) with the mouth's points refitted at a normalised exposure on a dark face."""
    g = exposure_gain(image, box)
    if g < MIN_EXPOSURE_GAIN:
        return p
    a = np.asarray(image)
    a = a.astype(np.float32) / 255.0 if a.dtype == np.uint8 else np.clip(np.asarray(a, np.float32), 0, 1)
    q = landmarks_in_box(_exposed(a, g), box)
    p = np.array(p, np.float64)
    p[48:68] = q[48:68]
    return p


def fit_landmarks(frame, box, *, face_px: float = 200.0, points68=None, exposure: bool = True,
                  mirror: bool = False) -> np.ndarray:
    """dlib's 68 landmarks (frame px) in a face ``box`` (x0, y0, x1, y1), fitted on a bicubic
    upscale of the box's neighbourhood when the box is narrower than ``face_px``; on a dark face
    the mouth's at a normalised exposure.

    dlib's shape predictor reads single pixels: on a GRID face (a ~100 px box) its points move in
    pixel steps, and a box carried from the previous frame can lag a syllable (GRID bbaf2n frame
    49: opening 0.063 where the frame measures 0.118). Fitted at 2x with one refit
    (``DriverParams.landmark_refits``), the tracked opening follows the one measured on 720 px
    upscaled frames with r 0.981-0.997 on the six GRID clips (0.950-0.997 before) and 0.943-0.989
    on mirrored side-lit, rotated small-face and dim noisy copies (0.952-0.979; the dim noisy one
    0.952 -> 0.943: the noise is upscaled too).

    **Dark faces.** dlib reads a dark face's mouth as less open than it is: GRID clips with the skin
    darkened in linear light to a dark-skinned tone (median luma 0.28) read 0.72 / 0.90 of the
    original clips' opening (bbaf2n / lrwp9a; regression slope), 0.59 / 0.86 with the lips darkened
    too and the inner lips' pink and the teeth kept, and the dim noisy copy 0.60. When the middle of
    the face box has a median luma below :data:`EXPOSED_FACE_LUMA` the mouth's points (48-67) are
    fitted again on the frame brightened by one gain in linear light (an exposure change: the
    colours' ratios kept) that brings that median there (:func:`exposure_gain`; not for a gain below
    :data:`MIN_EXPOSURE_GAIN`): 0.85 / 1.00, 0.57 / 1.18 and 0.91 (r 0.84-1.00; the dark-lipped
    bbaf2n copy, whose slightly open mouth shows a pale slit between dark lips, stays under-read).
    Only the mouth: brightening the whole fit (a gamma, measured in an earlier version) read the dim
    copy's eyes more shut; a per-channel gain to a light skin colour did as well on the mouth except
    on the dark-lipped bbaf2n copy (0.54).
    ``points68``: the landmarks already found in ``box`` at 1x (returned as they are when no
    upscale is needed and the face is not dark). ``exposure=False``: no mouth refit (a fit whose
    points only place the next fit's box). ``mirror``: averaged with the mirror image's fit
    (:func:`mirror_averaged`)."""
    import cv2

    b = np.asarray(box, np.float64)
    k = min(4.0, float(face_px) / max(b[2] - b[0], 1.0))
    if k <= 1.0:
        return _landmarks_exposed(frame, b, exposure, mirror, points68)
    h, w = frame.shape[:2]
    pad = 0.5 * (b[2] - b[0])
    x0, y0 = max(0, int(b[0] - pad)), max(0, int(b[1] - pad))
    x1, y1 = min(w, int(math.ceil(b[2] + pad))), min(h, int(math.ceil(b[3] + pad)))
    if x1 - x0 < 2 or y1 - y0 < 2:
        return _landmarks_exposed(frame, b, exposure, mirror)
    # the bicubic overshoot is clipped by landmarks_in_box's conversion to uint8
    crop = cv2.resize(np.ascontiguousarray(frame[y0:y1, x0:x1]), None, fx=k, fy=k, interpolation=cv2.INTER_CUBIC)
    shift = np.array([x0, y0], np.float64)
    up = (b.reshape(2, 2) - shift + 0.5) * k - 0.5
    return (_landmarks_exposed(crop, up.ravel(), exposure, mirror) + 0.5) / k - 0.5 + shift


def carried_box(points68: np.ndarray, ref_box, ref_points: np.ndarray):
    """The detector box ``ref_box`` (found with ``ref_points``) moved and scaled with the landmarks."""
    c0, c1 = ref_points.mean(axis=0), points68.mean(axis=0)
    k = float(np.ptp(points68, axis=0).max() / max(np.ptp(ref_points, axis=0).max(), 1e-6))
    bc = np.array([(ref_box[0] + ref_box[2]) / 2, (ref_box[1] + ref_box[3]) / 2])
    half = np.array([ref_box[2] - ref_box[0], ref_box[3] - ref_box[1]]) * k / 2
    c = c1 + (bc - c0) * k
    return (c[0] - half[0], c[1] - half[1], c[0] + half[0], c[1] + half[1])


def refit_in_carried_boxes(image, points68, box, ref_points, *, times: int, face_px: float = 200.0,
                           exposure: bool = True, mirror: bool = False) -> np.ndarray:
    """``points68`` fitted again ``times`` times with :func:`fit_landmarks`, each time in the detector
    ``box`` (found with ``ref_points``) carried by the last fit's points (:func:`carried_box`); on a
    dark face only the last fit refits the mouth at a normalised exposure (unless ``exposure`` is
    False) and, with ``mirror``, is averaged with the mirror image's (:func:`mirror_averaged`): the
    earlier fits only place the next box."""
    p = np.asarray(points68, np.float64)
    for i in range(times):
        p = fit_landmarks(image, carried_box(p, box, ref_points), face_px=face_px,
                          exposure=exposure and i == times - 1, mirror=mirror and i == times - 1)
    return p


def refine_landmarks(image, box, points68, *, face_px: float = 200.0, refits: int = 1,
                     exposure: bool = True, mirror: bool = False) -> np.ndarray:
    """(68, 2) landmarks of the face dlib found in ``box`` with ``points68``, read as the driver's
    tracker reads a frame's: fitted with :func:`fit_landmarks` (upscaled below ``face_px``), then
    ``refits`` times again in the box the points carry (:func:`refit_in_carried_boxes`); on a dark
    face the last fit refits the mouth at a normalised exposure unless ``exposure`` is False.
    ``mirror``: the whole refinement repeated on the mirror image (its box and points mirrored), the
    two results averaged (left and right swapped back: :data:`facetex.geometry.FLIP68`); each side's
    box carried by its own fits, the average scatters less than with only the last fit mirrored
    (:func:`mirror_averaged`, the tracker's): leave-out mouth SSIM over static, 5 folds, Williams
    +0.0559 against +0.0541, Chavez +0.0506 against +0.0487, Koizumi's face +0.0149 against +0.0124."""
    p0 = np.asarray(points68, np.float64)
    if mirror:
        flipped, fbox = _mirrored(image, box)
        w = flipped.shape[1]
        q = refine_landmarks(flipped, fbox, _mirror_points(p0, w), face_px=face_px, refits=refits, exposure=exposure)
        p = refine_landmarks(image, box, p0, face_px=face_px, refits=refits, exposure=exposure)
        return (p + _mirror_points(q, w)) / 2
    p = fit_landmarks(image, box, face_px=face_px, points68=p0, exposure=exposure and refits == 0)
    return refit_in_carried_boxes(image, p, box, p0, times=refits, face_px=face_px, exposure=exposure)
