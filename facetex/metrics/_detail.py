"""Beyond the paper: the skin's fine detail at native resolution, and how much the eyes, brows,
lips and the background changed."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import BadInputError
from ._paper import (
    PATCH_SIZE,
    _as_points,
    _luminance,
    _points68,
    skin_patch_frames,
    working_scale,
)

DETAIL_SIGMA = 2.0  # px, native: the high-pass is luminance minus its Gaussian blur of this sigma


MIN_SKIN_FRACTION = 0.2  # of a patch: with less skin than this a skin-only detail is NaN


def skin_detail(image, points68=None, *, sigma: float = DETAIL_SIGMA, source=None, per_patch: bool = False,
                mask=None):
    """Fine skin detail: std (0–255 scale) of ``L − G_sigma * L`` over the forehead and both
    cheek patches of :func:`skin_patch_frames`, at the image's own resolution (the patch
    pixels are sampled with nearest-neighbour, so no interpolation smooths them).
    ``mask`` (H, W) in [0, 1]: only the patch pixels where it is > 0.5 count (NaN for a patch
    with less than :data:`MIN_SKIN_FRACTION` of them)."""
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] < 3:
        raise BadInputError(f"expected an (H, W, 3) image, got shape {img.shape}")
    if img.max() > 1.5:
        img = img / 255.0
    p = _points68(img, points68, source)
    lum = _luminance(img) * 255.0
    hp = lum - cv2.GaussianBlur(lum, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    side = int(round(PATCH_SIZE / working_scale(img.shape)))
    if mask is not None:
        mask = np.asarray(mask, np.float32)
        if mask.shape != img.shape[:2]:
            raise BadInputError(f"mask has shape {mask.shape}, the image {img.shape[:2]}")
    values = {}
    for name, m in skin_patch_frames(p, img.shape).items():
        patch = cv2.warpAffine(hp, m, (side, side), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_REFLECT)
        if mask is None:
            values[name] = float(patch.std())
            continue
        keep = cv2.warpAffine(mask, m, (side, side), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT) > 0.5
        values[name] = float(patch[keep].std()) if keep.mean() >= MIN_SKIN_FRACTION else float("nan")
    mean = float(np.nanmean(list(values.values()))) if mask is not None else float(np.mean(list(values.values())))
    return (mean, values) if per_patch else mean


def _abs_change(a, b) -> np.ndarray:
    a = np.asarray(a, np.float32)
    b = np.asarray(b, np.float32)
    if a.shape != b.shape:
        raise BadInputError(f"images differ in shape: {a.shape} vs {b.shape}")
    if max(float(a.max()), float(b.max())) > 1.5:
        a, b = a / 255.0, b / 255.0
    d = np.abs(a - b) * 255.0
    return d.mean(axis=2) if d.ndim == 3 else d


def protected_change(output, content, *, points=None, source=None) -> float:
    """Mean |output − content| (0–255, averaged over channels) over the eyes, brows and lips
    of the content (:func:`facetex.geometry.skin.protected_mask`)."""
    from ..geometry.skin import protected_mask

    p = _points68(content, points, source)
    m = protected_mask(p, np.asarray(content).shape[:2])
    return float(_abs_change(output, content)[m].mean()) if m.any() else 0.0


def face_area_mask(image, points68, *, mesh=None, margin: float = 0.03) -> np.ndarray:
    """bool (H, W): the face (jaw + forehead outline, united with the mesh's face oval when
    ``mesh`` is given, and with the head region where the transfer may find skin: up to the
    hairline, the temples and the jaw edge) grown by ``margin`` × face width. Its complement
    is the background."""
    from ..geometry.masks import disc, face_outline, face_width
    from ..geometry.segment import head_region_mask
    from ..geometry.skin import FACE_OVAL_468

    p = _as_points(points68, "points68")
    h, w = np.asarray(image).shape[:2]
    m = np.zeros((h, w), np.uint8)
    cv2.fillPoly(m, [np.round(face_outline(p) * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
    if mesh is not None:
        oval = np.asarray(mesh)[list(FACE_OVAL_468), :2]
        cv2.fillPoly(m, [np.round(oval * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
    m |= head_region_mask(p, (h, w), mesh=mesh).astype(np.uint8)
    r = max(1, int(round(margin * face_width(p))))
    m = cv2.dilate(m, disc(r))
    return m.astype(bool)


def background_change(output, content, *, points=None, mesh=None, source=None) -> float:
    """Mean |output − content| (0–255) outside :func:`face_area_mask` of the content."""
    p = _points68(content, points, source)
    bg = ~face_area_mask(content, p, mesh=mesh)
    return float(_abs_change(output, content)[bg].mean()) if bg.any() else 0.0
