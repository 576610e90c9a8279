"""dlib's aligned face chips (``get_face_chip_details`` / ``extract_image_chip``) without dlib.

dlib fits a similarity transform (Umeyama, least squares) from a mean-face template to
33 of the 68 landmarks (eyebrows and lower lip left out), then samples a ``size`` ×
``size`` chip whose outer pixel centres span the fitted square, bilinearly. When the
chip is much smaller than its square in the image dlib first halves the image with a
pyramid; :func:`face_chip` does the same with ``cv2.pyrDown``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from skimage.transform import SimilarityTransform

from ..errors import BadInputError

# dlib's mean face shape for landmarks 17..67 in the unit square (dlib/image_transforms/
# interpolation.h, get_face_chip_details); data, indexed by landmark number.
_MEAN_FACE_X = np.array([
    0.000213256, 0.0752622, 0.18113, 0.29077, 0.393397, 0.586856, 0.689483, 0.799124,
    0.904991, 0.98004, 0.490127, 0.490127, 0.490127, 0.490127, 0.36688, 0.426036,
    0.490127, 0.554217, 0.613373, 0.121737, 0.187122, 0.265825, 0.334606, 0.260918,
    0.182743, 0.645647, 0.714428, 0.793132, 0.858516, 0.79751, 0.719335, 0.254149,
    0.340985, 0.428858, 0.490127, 0.551395, 0.639268, 0.726104, 0.642159, 0.556721,
    0.490127, 0.423532, 0.338094, 0.290379, 0.428096, 0.490127, 0.552157, 0.689874,
    0.553364, 0.490127, 0.42689])
_MEAN_FACE_Y = np.array([
    0.106454, 0.038915, 0.0187482, 0.0344891, 0.0773906, 0.0773906, 0.0344891,
    0.0187482, 0.038915, 0.106454, 0.203352, 0.307009, 0.409805, 0.515625, 0.587326,
    0.609345, 0.628106, 0.609345, 0.587326, 0.216423, 0.178758, 0.179852, 0.231733,
    0.245099, 0.244077, 0.231733, 0.179852, 0.178758, 0.216423, 0.244077, 0.245099,
    0.780233, 0.745405, 0.727388, 0.742578, 0.727388, 0.745405, 0.780233, 0.864805,
    0.902192, 0.909281, 0.902192, 0.864805, 0.784792, 0.778746, 0.785343, 0.778746,
    0.784792, 0.824182, 0.831803, 0.824182])
# landmarks used for the fit: nose, eyes, outer lips and upper inner lip
CHIP_POINTS = np.array([i for i in range(27, 68) if not (55 <= i <= 59 or 65 <= i <= 67)])


def _check_points(points68) -> np.ndarray:
    p = np.asarray(points68, dtype=np.float64)
    if p.shape != (68, 2) or not np.isfinite(p).all():
        raise BadInputError(f"expected 68 finite (x, y) landmarks, got an array of shape {p.shape}")
    return p


def face_chip_details(points68, size: int = 150, padding: float = 0.25) -> tuple[tuple[float, ...], float]:
    """dlib's chip details: the rectangle (left, top, right, bottom) in the image and its
    rotation angle (radians) for a ``size`` chip with ``padding`` (fraction of the face)."""
    p = _check_points(points68)
    if size < 2 or padding < 0:
        raise BadInputError(f"chip size must be >= 2 and padding >= 0, got {size} and {padding}")
    template = np.stack([_MEAN_FACE_X, _MEAN_FACE_Y], axis=1)[CHIP_POINTS - 17]
    chip_pts = (padding + template) / (2 * padding + 1) * size
    tform = SimilarityTransform.from_estimate(chip_pts, p[CHIP_POINTS])  # chip -> image
    if not tform:
        raise BadInputError("the face landmarks are degenerate: cannot align a face chip")
    m = tform.params
    angle = math.atan2(m[1, 0], m[0, 0])
    scale = math.hypot(m[0, 0], m[1, 0])
    cx, cy = tform(np.array([[size / 2.0, size / 2.0]]))[0]
    half = (size * scale - 1) / 2  # dlib's centered_drect: width counts pixels, so span is w-1
    return (cx - half, cy - half, cx + half, cy + half), angle


def chip_matrix_from_details(rect, angle: float, size: int = 150) -> np.ndarray:
    """2×3 affine image → chip for a dlib chip rectangle + angle: the rectangle's rotated
    corners land on the outer pixel centres 0 and size-1."""
    left, top, right, bottom = rect
    cx, cy = (left + right) / 2, (top + bottom) / 2
    k = (size - 1) / (right - left)
    c, s = math.cos(angle), math.sin(angle)
    rot = k * np.array([[c, s], [-s, c]])  # rotate by -angle, then scale
    shift = np.array([(size - 1) / 2, (size - 1) / 2]) - rot @ np.array([cx, cy])
    return np.concatenate([rot, shift[:, None]], axis=1)


def face_chip_matrix(points68, size: int = 150, padding: float = 0.25) -> np.ndarray:
    """2×3 affine (float64) mapping image pixel coordinates to chip pixel coordinates, as
    dlib's ``get_face_chip_details(shape, size, padding)``."""
    rect, angle = face_chip_details(points68, size, padding)
    return chip_matrix_from_details(rect, angle, size)


def _details_from_matrix(matrix, size: int) -> tuple[tuple[float, ...], float]:
    """Inverse of :func:`chip_matrix_from_details` (for similarity matrices)."""
    m = np.asarray(matrix, dtype=np.float64)
    k = math.hypot(m[0, 0], m[0, 1])
    angle = math.atan2(m[0, 1], m[0, 0])
    cx, cy = np.linalg.solve(m[:, :2], np.full(2, (size - 1) / 2) - m[:, 2])
    half = (size - 1) / k / 2
    return (cx - half, cy - half, cx + half, cy + half), angle


def _pyramid_plan(matrix, size: int, shape) -> tuple[int, int, int]:
    """(halvings, x0, y0): how often dlib halves the image before sampling a chip, and the
    top-left corner of the crop its pyramid is built on (its parity decides which pixels
    the 5-tap filter is centred on)."""
    (left, top, right, bottom), angle = _details_from_matrix(matrix, size)
    width = right - left + 1  # dlib's drectangle width
    levels, grow = 0, 2
    while ((width - 1) / 2 + 1) ** 2 > size * size:  # dlib: rect_down(rect).area() > chip size
        width = (width - 1) / 2 + 1
        levels += 1
        grow = 2 * grow + 2
    if levels == 0:
        return 0, 0, 0
    cx, cy = (left + right) / 2, (top + bottom) / 2
    c, s = math.cos(angle), math.sin(angle)
    xs, ys = [], []
    for x, y in ((left, top), (right, top), (left, bottom), (right, bottom)):
        xs.append(cx + c * (x - cx) - s * (y - cy))
        ys.append(cy + s * (x - cx) + c * (y - cy))
    x0 = min(max(0.0, min(xs) - grow), shape[1] - 4)
    y0 = min(max(0.0, min(ys) - grow), shape[0] - 4)
    return levels, max(0, int(math.floor(x0 + 0.5))), max(0, int(math.floor(y0 + 0.5)))


# image -> half-size image coordinates as dlib's chips sample them: dlib's pyramid maps
# x -> x/2 - (1.25, 0.75) though its pixels are centred on 2i + 2 (cv2.pyrDown: on 2i), so
# relative to pyrDown it samples at x/2 + (-0.25, +0.25)
_HALF = np.array([[2.0, 0.0, 0.5], [0.0, 2.0, -0.5], [0.0, 0.0, 1.0]])


def warp_chip(image: np.ndarray, matrix, size: int = 150) -> np.ndarray:
    """Sample the ``size``² chip of ``image`` for an image → chip similarity ``matrix``,
    bilinear, black outside, halving large images first as dlib does."""
    img = np.asarray(image)
    if img.ndim not in (2, 3) or img.shape[0] < 4 or img.shape[1] < 4:
        raise BadInputError(f"expected an (H, W, 3) image, got an array of shape {img.shape}")
    img = img.astype(np.float32, copy=False)
    matrix = np.asarray(matrix, dtype=np.float64)
    levels, x0, y0 = _pyramid_plan(matrix, size, img.shape)
    if levels:
        img = img[y0:, x0:]
        matrix = matrix @ np.array([[1.0, 0.0, x0], [0.0, 1.0, y0], [0.0, 0.0, 1.0]])
    for _ in range(levels):
        if min(img.shape[:2]) < 4:
            break
        img = cv2.pyrDown(img)
        matrix = matrix @ _HALF
    return cv2.warpAffine(img, matrix, (size, size), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def face_chip(image: np.ndarray, points68, size: int = 150, padding: float = 0.25) -> np.ndarray:
    """The aligned ``size``² float32 chip of ``image`` (H, W, C), bilinear, black outside,
    like ``dlib.get_face_chip`` (including its half-size pyramid for large faces)."""
    return warp_chip(image, face_chip_matrix(points68, size, padding), size)


def _pyr_down_torch(x):
    """cv2.pyrDown in torch: 5×5 binomial blur (reflect-101 border), keep even pixels."""
    import torch
    import torch.nn.functional as F

    k1 = torch.tensor([1.0, 4.0, 6.0, 4.0, 1.0], dtype=x.dtype, device=x.device) / 16
    k = (k1[:, None] * k1[None, :]).expand(x.shape[1], 1, 5, 5)
    return F.conv2d(F.pad(x, (2, 2, 2, 2), mode="reflect"), k, stride=2, groups=x.shape[1])


def face_chip_tensor(images, matrix, size: int = 150):
    """Differentiable :func:`warp_chip`: ``images`` (N, C, H, W) torch tensor, ``matrix``
    (2, 3) or (N, 2, 3) image → chip affine (numpy or torch, from :func:`face_chip_matrix`);
    returns (N, C, size, size), bilinear (affine_grid / grid_sample), zeros outside, with
    dlib's half-size pyramid for large faces."""
    import torch
    import torch.nn.functional as F

    if images.ndim != 4 or min(images.shape[2:]) < 4:
        raise BadInputError(f"expected images of shape (N, C, H, W), got {tuple(images.shape)}")
    n = images.shape[0]
    m = np.asarray(matrix.detach().cpu() if torch.is_tensor(matrix) else matrix, dtype=np.float64)
    if m.ndim == 2:
        m = np.broadcast_to(m, (n, 2, 3))
    if m.shape != (n, 2, 3):
        raise BadInputError(f"expected a (2, 3) or ({n}, 2, 3) matrix, got {m.shape}")
    if n > 1 and not np.allclose(m, m[:1]):
        return torch.cat([face_chip_tensor(images[i:i + 1], m[i], size) for i in range(n)])
    full = np.vstack([m[0], [0.0, 0.0, 1.0]])
    levels, x0, y0 = _pyramid_plan(full[:2], size, images.shape[2:])
    if levels:
        images = images[:, :, y0:, x0:]
        full = full @ np.array([[1.0, 0.0, x0], [0.0, 1.0, y0], [0.0, 0.0, 1.0]])
    for _ in range(levels):
        if min(images.shape[2:]) < 4:
            break
        images = _pyr_down_torch(images)
        full = full @ _HALF
    h, w = images.shape[2:]

    def norm(width, height):  # pixel -> [-1, 1] coordinates (align_corners=True)
        return np.array([[2 / (width - 1), 0, -1], [0, 2 / (height - 1), -1], [0, 0, 1]])

    theta = norm(w, h) @ np.linalg.inv(full) @ np.linalg.inv(norm(size, size))
    theta = torch.as_tensor(theta[:2], dtype=images.dtype, device=images.device).expand(n, 2, 3)
    grid = F.affine_grid(theta, [n, images.shape[1], size, size], align_corners=True)
    return F.grid_sample(images, grid, mode="bilinear", padding_mode="zeros", align_corners=True)
