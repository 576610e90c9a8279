"""The paper's measures (FaceTex §3.1): the landmark error E, the texture similarity S on three
skin patches at the 1000 px working size, and (beyond the paper) the identity distance."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import BadInputError
from ..io import LUMA_BT601, ImageLike, image_args
from ..landmarks import eye_centres

WORKING_SIZE = 1000  # px, long edge at which the paper measures E and S
#: ``facetex metrics`` reads larger images reduced on load to this many pixels (2000 x 2000):
#: the paper's measures are taken at 1000 px, and a 36 MP photo at full resolution takes
#: minutes and several GB (issue 23). The functions here take any size.
METRICS_MAX_PIXELS = 4_000_000
PATCH_SIZE = 100  # px at WORKING_SIZE (§3.1: 100 × 100 skin patches)
SKIN_PATCHES = ("forehead", "left_cheek", "right_cheek")


@dataclass(frozen=True)
class LandmarkError:
    """``mse_px2``: mean over the 66 points of the squared distance (px², the paper's E);
    ``rms_px``: its square root (px), easier to read."""

    mse_px2: float
    rms_px: float


def _as_points(p, name: str) -> np.ndarray:
    p = np.asarray(p, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2:
        raise BadInputError(f"{name} must be an (N, 2) array of points, got shape {p.shape}")
    return p


def landmark_error_points(points_a, points_b, *, scale_a: float = 1.0, scale_b: float = 1.0) -> LandmarkError:
    """E between two point sets: (1/N) Σ_k ‖s_a·a_k − s_b·b_k‖² in px² (and the RMS in px).

    ``scale_*`` bring each set to the working size (WORKING_SIZE / long edge)."""
    a = _as_points(points_a, "points_a") * scale_a
    b = _as_points(points_b, "points_b") * scale_b
    if a.shape != b.shape:
        raise BadInputError(f"point sets differ in shape: {a.shape} vs {b.shape}")
    mse = float(np.mean(np.sum((a - b) ** 2, axis=1)))  # FaceTex §3.1 landmark error
    return LandmarkError(mse, float(np.sqrt(mse)))


def working_scale(image_or_shape) -> float:
    """Factor from an image's pixels to the 1000 px long-edge working size."""
    shape = getattr(image_or_shape, "shape", image_or_shape)
    return WORKING_SIZE / float(max(shape[0], shape[1]))


def _points68(image, points68, source):
    if points68 is not None:
        return _as_points(points68, "points68")
    from ..landmarks import detect_face

    return detect_face(image, source=source).points68


@image_args("image_a", "image_b", sources={"image_a": "source_a", "image_b": "source_b"})
def landmark_error(image_a: ImageLike, image_b: ImageLike, *, points_a: np.ndarray | None = None,
                   points_b: np.ndarray | None = None, source_a: str | None = None,
                   source_b: str | None = None) -> LandmarkError:
    """E(a, b) on the 66 FaceTex landmarks, each image's points scaled to a 1000 px long edge.

    Parameters
    ----------
    image_a, image_b : str, os.PathLike, PIL.Image.Image or numpy.ndarray
        Files, PIL images or (H, W, 3) uint8 / uint16 / float [0, 1] arrays.
    points_a, points_b : numpy.ndarray, optional
        Their (68, 2) landmarks; detected (largest face) when not given.
    source_a, source_b : str, optional
        The files to name in errors (the paths themselves when the images are paths).

    Returns
    -------
    LandmarkError
        ``mse_px2`` (E, px²) and ``rms_px``.

    Raises
    ------
    facetex.NoFaceError
        No face in an image whose points were not given."""
    from ..landmarks import points66

    pa = points66(_points68(image_a, points_a, source_a))
    pb = points66(_points68(image_b, points_b, source_b))
    return landmark_error_points(pa, pb, scale_a=working_scale(image_a), scale_b=working_scale(image_b))


def normalized_correlation(p, q) -> float:
    """Eq. 8 (FaceTex): normalized correlation coefficient of two equally sized patches."""
    p = np.asarray(p, dtype=np.float64).ravel()
    q = np.asarray(q, dtype=np.float64).ravel()
    if p.shape != q.shape:
        raise BadInputError(f"patches differ in size: {p.size} vs {q.size}")
    p = p - p.mean()
    q = q - q.mean()
    denom = np.sqrt(np.sum(p * p) * np.sum(q * q))
    return float(np.sum(p * q) / denom) if denom > 0 else 0.0


def skin_patch_frames(points68, image_shape) -> dict[str, np.ndarray]:
    """2 × 3 affine maps (image → patch) of the forehead and cheek patches.

    Positions are landmark-relative, so the same facial spot is sampled in both images:
    the frame's x axis follows the eye line; with ``d`` the distance between the eye
    centres, the forehead patch's lower edge lies 0.08·d above the brow arches
    (points 19 and 24), each cheek patch at the centroid of the jaw point 2 (or 14), the
    nostril point 31 (35), the lower eyelid 41 (46) and the mouth corner 48 (54).
    The patch side is 100 px at the 1000 px working size, scaled with the image."""
    p = _as_points(points68, "points68")
    if p.shape[0] != 68:
        raise BadInputError(f"need 68 landmarks, got {p.shape[0]}")
    left_eye, right_eye = eye_centres(p)
    ex = right_eye - left_eye
    d = float(np.hypot(*ex))
    ex /= d
    ey = np.array([-ex[1], ex[0]])  # image "down" direction for an upright face
    side = PATCH_SIZE / working_scale(image_shape)
    centres = {
        # just above the brow arches: foreheads are short, hair starts soon above
        "forehead": p[[19, 24]].mean(0) - (side / 2 + 0.08 * d) * ey,
        "left_cheek": p[[2, 31, 41, 48]].mean(0),
        "right_cheek": p[[14, 35, 46, 54]].mean(0),
    }
    frames = {}
    for name, c in centres.items():
        # patch pixel (u, v) samples image point c + (u - side/2)·ex + (v - side/2)·ey
        origin = c - side / 2 * (ex + ey)
        to_image = np.column_stack([ex, ey, origin])
        frames[name] = cv2.invertAffineTransform(to_image)
    return frames


def _luminance(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image, dtype=np.float32)
    if image.ndim == 2:
        return image
    return image[..., :3] @ LUMA_BT601


def skin_patches(image, points68, *, gray: bool = True) -> dict[str, np.ndarray]:
    """The three skin patches (forehead, left cheek, right cheek) of an image."""
    img = _luminance(image) if gray else np.asarray(image, dtype=np.float32)
    side = int(round(PATCH_SIZE / working_scale(img.shape)))
    return {
        name: cv2.warpAffine(img, m, (side, side), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        for name, m in skin_patch_frames(points68, img.shape).items()
    }


@image_args("image_a", "image_b", sources={"image_a": "source_a", "image_b": "source_b"})
def texture_similarity(image_a: ImageLike, image_b: ImageLike, *, points_a: np.ndarray | None = None,
                       points_b: np.ndarray | None = None, source_a: str | None = None,
                       source_b: str | None = None, gray: bool = True, per_patch: bool = False) -> float | dict:
    """S(a, b): Eq. 8 on the forehead and both cheek patches, averaged over the three.

    Patches of both images are resampled to the same size (100 px at the 1000 px scale of
    ``image_a``).

    Parameters
    ----------
    image_a, image_b : str, os.PathLike, PIL.Image.Image or numpy.ndarray
        Files, PIL images or (H, W, 3) uint8 / uint16 / float [0, 1] arrays.
    points_a, points_b : numpy.ndarray, optional
        Their (68, 2) landmarks; detected (largest face) when not given.
    source_a, source_b : str, optional
        The files to name in errors (the paths themselves when the images are paths).
    gray : bool
        Correlate BT.601 luminance (texture is mostly luminance detail); False: the RGB
        values of a patch together.
    per_patch : bool
        Also return the three patches' values.

    Returns
    -------
    float or tuple
        S in [-1, 1]; with ``per_patch`` ``(S, {patch: S})``.

    Raises
    ------
    facetex.NoFaceError
        No face in an image whose points were not given."""
    pa = _points68(image_a, points_a, source_a)
    pb = _points68(image_b, points_b, source_b)
    patches_a = skin_patches(image_a, pa, gray=gray)
    patches_b = skin_patches(image_b, pb, gray=gray)
    values = {}
    for name in SKIN_PATCHES:
        qa, qb = patches_a[name], patches_b[name]
        if qb.shape != qa.shape:
            qb = cv2.resize(qb, qa.shape[1::-1], interpolation=cv2.INTER_AREA)
        values[name] = normalized_correlation(qa, qb)
    mean = float(np.mean(list(values.values())))
    return (mean, values) if per_patch else mean


@image_args("image_a", "image_b", sources={"image_a": "source_a", "image_b": "source_b"})
def identity_distance(image_a: ImageLike, image_b: ImageLike, *, points_a: np.ndarray | None = None,
                      points_b: np.ndarray | None = None, source_a: str | None = None,
                      source_b: str | None = None) -> float:
    """Euclidean distance of the FaceRecognitionNet (dlib ResNet) descriptors of two faces.

    Parameters
    ----------
    image_a, image_b : str, os.PathLike, PIL.Image.Image or numpy.ndarray
        Files, PIL images or (H, W, 3) uint8 / uint16 / float [0, 1] arrays.
    points_a, points_b : numpy.ndarray, optional
        Their (68, 2) landmarks; detected (largest face) when not given.
    source_a, source_b : str, optional
        The files to name in errors (the paths themselves when the images are paths).

    Returns
    -------
    float
        The distance; < 0.6 means the same person by dlib's convention.

    Raises
    ------
    facetex.NoFaceError
        No face in an image whose points were not given."""
    from ..nets.dlib_resnet import face_descriptor

    da = face_descriptor(image_a, _points68(image_a, points_a, source_a))
    db = face_descriptor(image_b, _points68(image_b, points_b, source_b))
    return float(np.linalg.norm(da - db))
