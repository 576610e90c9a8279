"""The transfer's working region: the face crop and the points mapped into it, the checks of
the input images, large images worked on in a reduced part (issue 23), and the optimised region
pasted back into the full content image."""

from __future__ import annotations

import math

import cv2
import numpy as np

from ..errors import BadImageError, BadInputError
from ..io import to_float32

CROP_MARGIN = 0.12  # face crop margin around the face outline, × face width


# ---------------------------------------------------------------- regions
def face_crop_box(points68, shape, margin: float = CROP_MARGIN) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of the face (jaw + forehead arc) grown by ``margin`` × face width."""
    from ..geometry.masks import face_outline, face_width

    outline = face_outline(points68)
    pad = margin * face_width(points68)
    x0, y0 = np.floor(outline.min(0) - pad).astype(int)
    x1, y1 = np.ceil(outline.max(0) + pad).astype(int)
    h, w = shape[:2]
    return max(0, x0), max(0, y0), min(w, x1), min(h, y1)


def _resize(image: np.ndarray, size_wh: tuple[int, int]) -> np.ndarray:
    shrink = size_wh[0] < image.shape[1]
    interp = cv2.INTER_AREA if shrink else cv2.INTER_CUBIC
    return np.clip(cv2.resize(image, size_wh, interpolation=interp), 0.0, 1.0).astype(np.float32)


def _map_points(points, box, scale_xy):
    """Points of the full image → points of the (cropped, resized) region (pixel centres)."""
    p = np.asarray(points, np.float64)
    x0, y0 = box[0], box[1]
    return np.column_stack([(p[:, 0] - x0 + 0.5) * scale_xy[0] - 0.5, (p[:, 1] - y0 + 0.5) * scale_xy[1] - 0.5])


def _check_rgb(image, name: str, lazy: bool = False) -> np.ndarray:
    """``image`` as float32 RGB; with ``lazy`` an integer image over NATIVE_MAX_PIXELS stays as it
    is (its reduced part is made float, see :func:`_native_part`)."""
    a = np.asarray(image)
    if a.ndim != 3 or a.shape[2] != 3:
        raise BadImageError(f"{name} must be an (H, W, 3) RGB image, got shape {a.shape}")
    if not (lazy and (stays_integer(a) or stays_float(a))):
        a = to_float32(a)
    if min(a.shape[:2]) < 32:
        raise BadImageError(f"{name} of {a.shape[1]}x{a.shape[0]} px is too small: use at least 32 px")
    return a


def _init_image(init, content: np.ndarray) -> np.ndarray:
    """An ``init`` image (not "content" / "random") as float32 RGB of the content's size, checked."""
    if isinstance(init, str):
        raise BadInputError(f"init must be 'content', 'random' or an image array, not {init!r}")
    ini = _check_rgb(init, "init image")
    if ini.shape != content.shape:
        raise BadImageError(f"init image is {ini.shape[1]}x{ini.shape[0]} px, the content "
                            f"{content.shape[1]}x{content.shape[0]}: it must have the content's size")
    return ini


# ---------------------------------------------------------------- large images (issue 23)
#: Largest content or style image the pipeline works on as it is (1.5 MP; the paper's headshots
#: are 1000 px). Above it, the work is done on the face's neighbourhood (the crop box grown by
#: :data:`NATIVE_CONTEXT`, or the whole image with ``crop="image"``) reduced to at most this many
#: pixels, and only the change is brought back to the content's own pixels: a 36 MP photo took
#: minutes and GBs in the pre-warp and detail stages at full resolution (issue 23).
NATIVE_MAX_PIXELS = 1_500_000
NATIVE_CONTEXT = 0.1  # × the crop box's longer side: room for the skin mask and the face mesh


def stays_integer(image) -> bool:
    """Whether ``image`` is a uint8 / uint16 RGB array over :data:`NATIVE_MAX_PIXELS`, which the
    pipeline keeps as it is: only its reduced face region is made float (a 36 MP photo as float
    is 0.4 GB)."""
    return (isinstance(image, np.ndarray) and image.dtype in (np.uint8, np.uint16) and image.ndim == 3
            and image.shape[2] == 3 and image.shape[0] * image.shape[1] > NATIVE_MAX_PIXELS)


def stays_float(image) -> bool:
    """Whether ``image`` is a float RGB array over :data:`NATIVE_MAX_PIXELS`, which the pipeline
    keeps as it is, like :func:`stays_integer`: its reduced face region is made float32 and
    clipped to [0, 1] (a 6000 x 6000 float64 array is 0.8 GB, its float32 copy another 0.4 GB;
    issue 23). Its values must have passed :func:`facetex.io.check_float_pixels`."""
    return (isinstance(image, np.ndarray) and image.dtype.kind == "f" and image.ndim == 3
            and image.shape[2] == 3 and image.shape[0] * image.shape[1] > NATIVE_MAX_PIXELS)


def _clipped_float32(image: np.ndarray, copy: bool = False) -> np.ndarray:
    """A float image as float32 clipped to [0, 1], converted in row strips (no float64 or
    boolean temporaries of its size); the same values as ``np.clip(to_float32(image), 0, 1)``.
    Without ``copy`` a float32 image already in [0, 1] is returned as it is."""
    if not copy and image.dtype == np.float32 and (image.size == 0 or (image.min() >= 0 and image.max() <= 1)):
        return image
    out = np.empty(image.shape, np.float32)
    rows = max(1, (1 << 22) // max(1, image.size // max(1, image.shape[0])))
    for i in range(0, image.shape[0], rows):
        np.clip(image[i:i + rows], 0.0, 1.0, out=out[i:i + rows], casting="same_kind")
    return out


def detect_points68(image: np.ndarray, source=None) -> np.ndarray:
    """68 landmarks of the largest face; on an image over :data:`facetex.io.DETECT_MAX_PIXELS`
    found on a copy reduced to it, in the image's own pixels."""
    from ..io import DETECT_MAX_PIXELS
    from ..landmarks import detect_face

    h, w = image.shape[:2]
    if h * w <= DETECT_MAX_PIXELS:
        return detect_face(image, source=source).points68
    k = math.sqrt(DETECT_MAX_PIXELS / (h * w))
    if image.dtype.kind == "f":  # reduced from float32 in [0, 1], as when the caller's array was converted
        image = _clipped_float32(image)
    small = cv2.resize(image, (max(1, int(w * k)), max(1, int(h * k))), interpolation=cv2.INTER_AREA)
    to_full = (w / small.shape[1], h / small.shape[0])
    if small.dtype != np.uint8 and np.issubdtype(small.dtype, np.floating):
        # the detector's own uint8 conversion, made here: detect_face would first copy the float
        # image (as_image) and convert it with float temporaries of its size (issue 23)
        from ..landmarks import _as_uint8_rgb

        small = _as_uint8_rgb(np.clip(small, 0.0, 1.0, out=small))
    return _map_points(detect_face(small, source=source).points68, (0, 0), to_full)


def _native_part(image: np.ndarray, points68, crop: str):
    """(part box (x0, y0, x1, y1) of ``image``, the part reduced to at most NATIVE_MAX_PIXELS,
    its points, (sx, sy) = reduced size / part size) of an image over NATIVE_MAX_PIXELS."""
    H, W = image.shape[:2]
    if crop == "face":
        x0, y0, x1, y1 = face_crop_box(points68, image.shape)
        pad = math.ceil(NATIVE_CONTEXT * max(x1 - x0, y1 - y0))
        part = (max(0, x0 - pad), max(0, y0 - pad), min(W, x1 + pad), min(H, y1 + pad))
    else:
        part = (0, 0, W, H)
    pw, ph = part[2] - part[0], part[3] - part[1]
    k = min(1.0, math.sqrt(NATIVE_MAX_PIXELS / (pw * ph)))
    sub = image[part[1]:part[3], part[0]:part[2]]
    if sub.dtype.kind == "f":  # a float array kept as it is (stays_float): the part as float32 in [0, 1]
        sub = _clipped_float32(sub)
    if k < 1.0:  # reduced in the image's own type (a uint8 photo is not made float at full size)
        sub = cv2.resize(np.ascontiguousarray(sub), (max(32, int(pw * k)), max(32, int(ph * k))),
                         interpolation=cv2.INTER_AREA)
    sub = np.clip(to_float32(sub), 0.0, 1.0)  # a new array: the caller's image is never written
    sx, sy = sub.shape[1] / pw, sub.shape[0] / ph
    return part, sub, _map_points(points68, part, (sx, sy)), (sx, sy)


def _paste_change(content: np.ndarray, part, scale_xy, before: np.ndarray, after: np.ndarray, box_small,
                  rows: int = 256, in_place: bool = False) -> np.ndarray:
    """``content`` with the change ``after − before`` of its reduced ``part`` (non-zero inside
    ``box_small`` only) brought to the part's full resolution (bilinear, strip by strip), as
    float32 (``content`` may be uint8 / uint16). ``in_place``: a float32 ``content`` that is the
    pipeline's own (the API's converted copy of a caller's array) is written and returned
    instead of copied (issue 23: a 6000 x 6000 image is 0.4 GB as float32)."""
    if content.dtype.kind == "f" and not (in_place and content.dtype == np.float32):
        out = _clipped_float32(content, copy=True)  # a float array kept as it is: clipped like as_image
    else:
        out = to_float32(content)
        if np.shares_memory(out, content) and not (in_place and out is content):
            out = out.copy()
    sx, sy = scale_xy
    delta = (after - before).astype(np.float32)
    pw, ph = part[2] - part[0], part[3] - part[1]
    fx0, fy0 = max(0, int((box_small[0] - 1) / sx)), max(0, int((box_small[1] - 1) / sy))
    fx1, fy1 = min(pw, math.ceil((box_small[2] + 1) / sx)), min(ph, math.ceil((box_small[3] + 1) / sy))
    xs = ((np.arange(fx0, fx1, dtype=np.float64) + 0.5) * sx - 0.5).astype(np.float32)
    for r0 in range(fy0, fy1, rows):
        r1 = min(fy1, r0 + rows)
        ys = ((np.arange(r0, r1, dtype=np.float64) + 0.5) * sy - 0.5).astype(np.float32)
        mx, my = np.meshgrid(xs, ys)
        d = cv2.remap(delta, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        view = out[part[1] + r0:part[1] + r1, part[0] + fx0:part[0] + fx1]
        view += d
        np.clip(view, 0.0, 1.0, out=view)
    return out


def _full_box(part, scale_xy, box_small, shape) -> tuple[int, int, int, int]:
    sx, sy = scale_xy
    return (max(0, part[0] + int(box_small[0] / sx)), max(0, part[1] + int(box_small[1] / sy)),
            min(shape[1], part[0] + math.ceil(box_small[2] / sx)),
            min(shape[0], part[1] + math.ceil(box_small[3] / sy)))


def _paste_region(region, content_w, out_w, skin_c, params) -> np.ndarray:
    """The region at its full resolution with the optimiser's *change* pasted in: the
    content's own detail above the working resolution survives instead of being blurred
    by the resampling; with the skin constraint nothing changes outside the skin."""
    rh, rw = region.shape[:2]
    delta = cv2.resize(out_w - content_w, (rw, rh), interpolation=cv2.INTER_CUBIC)
    if params.constraint == "skin":
        delta *= (skin_c > 0)[..., None]  # exactly nothing outside the skin (cubic rings 1–2 px)
    return np.clip(region + delta, 0.0, 1.0)


def _compose(content, region, box, out_region, params) -> np.ndarray:
    """The full image with the region replaced (feathered at inner crop edges when the whole
    crop may change)."""
    out = content.copy()
    rh, rw = region.shape[:2]
    if params.crop == "face" and params.constraint != "skin":
        alpha = _edge_feather((rh, rw), box, content.shape[:2])
        out[box[1]:box[3], box[0]:box[2]] = alpha[..., None] * out_region + (1 - alpha[..., None]) * region
    else:
        out[box[1]:box[3], box[0]:box[2]] = out_region
    return out


def _paste(content, region, box, content_w, out_w, skin_c, params) -> np.ndarray:
    return _compose(content, region, box, _paste_region(region, content_w, out_w, skin_c, params), params)


def _edge_feather(shape, box, full_shape, frac: float = 0.08) -> np.ndarray:
    """Blend weight of a pasted region: 1 inside, ramping to 0 at crop edges that lie inside
    the image (edges on the image border need no blending)."""
    h, w = shape
    r = max(2, int(frac * min(h, w)))
    y = np.ones(h, np.float32)
    x = np.ones(w, np.float32)
    ramp = (np.arange(r, dtype=np.float32) + 0.5) / r
    if box[1] > 0:
        y[:r] = np.minimum(y[:r], ramp)
    if box[3] < full_shape[0]:
        y[-r:] = np.minimum(y[-r:], ramp[::-1])
    if box[0] > 0:
        x[:r] = np.minimum(x[:r], ramp)
    if box[2] < full_shape[1]:
        x[-r:] = np.minimum(x[-r:], ramp[::-1])
    return np.outer(y, x)
