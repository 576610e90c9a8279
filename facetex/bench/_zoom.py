"""Zoomed face crops at native resolution, side by side: what a result looks like at 100 %.

Crops are cut at the *content's* landmarks from every image of the same geometry
(content, pre-warped style, outputs) and enlarged with nearest-neighbour, so pores,
bands, seams and checkerboards stay visible.
"""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

__all__ = ["ZOOM_REGIONS", "zoom_boxes", "zoom_sheet"]

ZOOM_REGIONS = ("forehead", "left cheek", "right cheek", "upper lip", "chin", "eyes", "mouth", "jaw edge")


def zoom_boxes(points68) -> dict[str, tuple[int, int, int, int]]:
    """(x, y, w, h) of each :data:`ZOOM_REGIONS` crop, sized by the eye-corner distance."""
    p = np.asarray(points68, np.float64)
    eye = float(np.linalg.norm(p[36] - p[45]))
    s = int(round(0.5 * eye))
    centres = {
        "forehead": (p[19] + p[24]) / 2 - [0, 0.45 * eye],
        "left cheek": (p[2] + p[31]) / 2 + [-0.1 * eye, -0.15 * eye],
        "right cheek": (p[14] + p[35]) / 2 + [0.1 * eye, -0.15 * eye],
        "upper lip": (p[33] + p[51]) / 2,
        "chin": p[8] - [0, 0.25 * eye],
        "eyes": (p[36] + p[45]) / 2,
        "mouth": (p[48] + p[54]) / 2,
        "jaw edge": p[4],
    }
    wide = {"eyes": (int(1.6 * eye), s), "mouth": (int(0.9 * eye), s), "upper lip": (int(0.9 * eye), int(0.3 * eye))}
    out = {}
    for k, c in centres.items():
        w, h = wide.get(k, (s, s))
        out[k] = (int(c[0] - w / 2), int(c[1] - h / 2), w, h)
    return out


def _u8(img) -> np.ndarray:
    a = np.asarray(img)
    if a.dtype != np.uint8:
        a = (np.clip(a, 0, 1) * 255 + 0.5).astype(np.uint8)
    return a if a.ndim == 3 else np.repeat(a[..., None], 3, 2)


def crop_padded(img: np.ndarray, box, zoom: int, fill=127) -> np.ndarray:
    """The (x, y, w, h) ``box`` of an (H, W, 3) image, ``fill`` where it leaves the image,
    enlarged ``zoom`` times with nearest neighbours (pixels stay visible at 100 %)."""
    x, y, w, h = box
    H, W = img.shape[:2]
    pad = np.full((h, w, 3), fill, img.dtype)
    x0, y0, x1, y1 = max(0, x), max(0, y), min(W, x + w), min(H, y + h)
    if x1 > x0 and y1 > y0:
        pad[y0 - y:y1 - y, x0 - x:x1 - x] = img[y0:y1, x0:x1]
    return cv2.resize(pad, (w * zoom, h * zoom), interpolation=cv2.INTER_NEAREST)


def _text(img, s, org, scale=0.5):
    cv2.putText(img, s, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1, cv2.LINE_AA)


def zoom_sheet(columns: Sequence[tuple[str, np.ndarray]], points68, *,
               regions: Sequence[str] = ("forehead", "left cheek", "right cheek", "chin"), zoom: int = 2,
               title: str | None = None) -> np.ndarray:
    """uint8 RGB sheet: one row per region, one column per (label, image); every image has
    the geometry of the content whose ``points68`` place the crops (images of another size
    are resized to the first column's size first)."""
    if not columns:
        raise ValueError("zoom_sheet needs at least one column")
    imgs = [_u8(im) for _, im in columns]
    h0, w0 = imgs[0].shape[:2]
    imgs = [im if im.shape[:2] == (h0, w0) else cv2.resize(im, (w0, h0), interpolation=cv2.INTER_AREA)
            for im in imgs]
    boxes = zoom_boxes(points68)
    gap, left, top = 4, 90, 22 + (20 if title else 0)
    rows = []
    for r in regions:
        cells = [crop_padded(im, boxes[r], zoom) for im in imgs]
        rows.append((r, np.concatenate([np.pad(c, ((0, 0), (0, gap), (0, 0)), constant_values=255) for c in cells], 1)))
    width = left + max(row.shape[1] for _, row in rows)
    height = top + sum(row.shape[0] + gap for _, row in rows)
    sheet = np.full((height, width, 3), 255, np.uint8)
    if title:
        _text(sheet, title, (4, 16), 0.55)
    cw = crop_padded(imgs[0], boxes[regions[0]], zoom).shape[1] + gap
    for i, (label, _) in enumerate(columns):
        _text(sheet, label[:28], (left + i * cw + 2, top - 6), 0.45)
    y = top
    for r, row in rows:
        _text(sheet, r, (4, y + 16), 0.45)
        sheet[y:y + row.shape[0], left:left + row.shape[1]] = row
        y += row.shape[0] + gap
    return sheet
