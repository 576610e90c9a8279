"""Face detection, 68-point landmarks (dlib) and the 468-point MediaPipe face mesh.

Coordinates are (x, y) pixels of the image passed in, with pixel centres at
integer coordinates (the dlib / OpenCV convention). The 68 points follow the
iBUG 300-W order, 0-based: jaw 0-16, brows 17-26, nose 27-35, eyes 36-47
(36 and 45 are the outer corners), outer lip 48-59 (48 and 54 are the mouth
corners), inner lip 60-67.

The two papers use subsets of it:

* FaceTex uses the 66-point CLM layout (its ref. [19]): the 68 iBUG points
  without the two inner-mouth corners 60 and 64 -> :data:`POINTS66_INDEX`.
* "What makes Tom Hanks look like Tom Hanks" uses the 49-point SDM layout
  (its ref. [29]): the 66 points without the 17 jaw points 0-16
  -> :data:`POINTS49_INDEX`.

Models are loaded lazily, once per process, under a lock; a forked worker of a
process pool loads its own copy on first use. Mesh inference is serialised by
the same lock; dlib calls are not, so parallelise with processes, not threads.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import threading
from dataclasses import dataclass
from typing import Literal, Sequence

import cv2
import numpy as np

from ._resources import model_path
from .errors import BadInputError, NoFaceError
from .io import ImageLike, image_args

__all__ = [
    "Face",
    "POINTS66_INDEX",
    "POINTS49_INDEX",
    "points66",
    "points49",
    "detect_faces",
    "detect_face",
    "landmarks_in_box",
    "eye_centres",
    "eye_distance",
    "face_mesh468",
    "MESH_INPUT_SIZE",
    "MESH_MIN_SCORE",
    "AUTO_UPSAMPLE_MAX_SIDE",
]


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


#: 0-based indices into the iBUG 68 points of the FaceTex / CLM 66-point layout.
POINTS66_INDEX: np.ndarray = _readonly(np.array([i for i in range(68) if i not in (60, 64)], dtype=np.intp))
#: 0-based indices into the iBUG 68 points of the Tom Hanks / SDM 49-point layout.
POINTS49_INDEX: np.ndarray = _readonly(np.array([i for i in range(17, 68) if i not in (60, 64)], dtype=np.intp))

#: Side (px) of the square crop the MediaPipe mesh network takes.
MESH_INPUT_SIZE = 192
#: Mesh face-presence probability below which face_mesh468 raises NoFaceError.
MESH_MIN_SCORE = 0.5
#: With upsample=None, images whose longer side is at most this are searched again
#: at 2x when nothing is found at 1x (dlib's HOG window is 80 px: faces down to ~40 px).
AUTO_UPSAMPLE_MAX_SIDE = 1200

Detector = Literal["hog", "cnn"]


def points66(p68: np.ndarray) -> np.ndarray:
    """The 66 FaceTex / CLM points (68 without inner-mouth corners 60, 64) of (68, 2) points."""
    return _check68(p68)[POINTS66_INDEX]


def points49(p68: np.ndarray) -> np.ndarray:
    """The 49 Tom Hanks / SDM points (68 without jaw 0-16 and 60, 64) of (68, 2) points."""
    return _check68(p68)[POINTS49_INDEX]


def eye_centres(points68) -> tuple[np.ndarray, np.ndarray]:
    """The centres (..., 2) of the two eyes (iBUG 36-41, then 42-47: image left first) of
    (..., 68, 2) landmarks."""
    p = np.asarray(points68, np.float64)
    return p[..., 36:42, :].mean(axis=-2), p[..., 42:48, :].mean(axis=-2)


def eye_distance(points68):
    """Distance between the eye centres (:func:`eye_centres`) of (68, 2) landmarks (a float), or
    of each face of a (..., 68, 2) stack (an array): the unit of a face's size."""
    a, b = eye_centres(points68)
    d = np.linalg.norm(b - a, axis=-1)
    return float(d) if d.ndim == 0 else d


def _check68(p68) -> np.ndarray:
    p = np.asarray(p68, dtype=np.float64)
    if p.shape != (68, 2):
        raise BadInputError(f"expected 68 landmark points of shape (68, 2), got shape {p.shape}")
    return p


def _scale_coords(a: np.ndarray, factor: float) -> np.ndarray:
    # pixel centres at integers: the image extent [-0.5, W-0.5] scales to [-0.5, fW-0.5] (as cv2.resize)
    return (a + 0.5) * factor - 0.5


@dataclass(frozen=True, eq=False)
class Face:
    """One detected face.

    Parameters
    ----------
    box : tuple of float
        (x0, y0, x1, y1) of the detector, pixels (may extend past the image edge).
    points68 : numpy.ndarray
        (68, 2) float64 iBUG landmarks (x, y), read-only.
    score : float
        Detector confidence (HOG SVM margin or MMOD CNN confidence; not a probability).
    """

    box: tuple[float, float, float, float]
    points68: np.ndarray
    score: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "box", tuple(float(v) for v in self.box))
        if len(self.box) != 4:
            raise BadInputError(f"a face box needs 4 numbers (x0, y0, x1, y1), got {len(self.box)}")
        object.__setattr__(self, "points68", _readonly(_check68(self.points68).copy()))
        object.__setattr__(self, "score", float(self.score))

    @property
    def points66(self) -> np.ndarray:
        """The 66-point FaceTex / CLM subset, (66, 2)."""
        return self.points68[POINTS66_INDEX]

    @property
    def points49(self) -> np.ndarray:
        """The 49-point Tom Hanks / SDM subset, (49, 2)."""
        return self.points68[POINTS49_INDEX]

    @property
    def area(self) -> float:
        x0, y0, x1, y1 = self.box
        return max(0.0, x1 - x0) * max(0.0, y1 - y0)

    def scaled(self, factor: float) -> "Face":
        """This face in an image resized by ``factor`` (pixel-centre convention, as cv2.resize)."""
        box = _scale_coords(np.asarray(self.box, dtype=np.float64), factor)
        return Face(tuple(box), _scale_coords(self.points68, factor), self.score)

    def __repr__(self) -> str:
        x0, y0, x1, y1 = self.box
        return f"Face(box=({x0:.1f}, {y0:.1f}, {x1:.1f}, {y1:.1f}), score={self.score:.3f})"


# ---------------------------------------------------------------------------
# lazily loaded models

_lock = threading.Lock()
_models: dict[str, object] = {}


@contextlib.contextmanager
def _stderr_silenced():
    """Discard what C++ code writes to file descriptor 2 meanwhile (Python errors still raise)."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _frontal_face_detector():
    """dlib's HOG frontal face detector. dlib builds it from a compressed copy in its library
    (~0.5 s per process); the same detector saved to a file loads in ~2 ms (identical
    detections, measured), so it is saved once to the cache folder, per dlib version."""
    import dlib

    from ._resources import cache_dir, writable_cache_dir

    name = f"dlib-{dlib.__version__}-frontal_face_detector.svm"
    path = cache_dir() / name
    if path.is_file():
        try:
            return dlib.fhog_object_detector(str(path))
        except RuntimeError:  # damaged: saved again below
            pass
    det = dlib.get_frontal_face_detector()
    folder = writable_cache_dir()
    if folder is None:  # no cache here: built each time
        return det
    path = folder / name
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:  # atomically: processes building a persona in parallel may race here
        det.save(str(tmp))
        os.replace(tmp, path)
    except (OSError, RuntimeError):  # no writable cache: built each time
        with contextlib.suppress(OSError):
            tmp.unlink()
    return det


def _model(name: str):
    m = _models.get(name)
    if m is not None:
        return m
    with _lock:
        m = _models.get(name)
        if m is None:
            import dlib

            if name == "hog":
                m = _frontal_face_detector()
            elif name == "cnn":
                m = dlib.cnn_face_detection_model_v1(str(model_path("mmod_human_face_detector.dat")))
            elif name == "shape68":
                m = dlib.shape_predictor(str(model_path("shape_predictor_68_face_landmarks.dat")))
            elif name == "mesh":
                from ai_edge_litert.interpreter import Interpreter

                path = str(model_path("face_landmark.tflite"))
                with _stderr_silenced():  # LiteRT prints "INFO: Created TensorFlow Lite XNNPACK delegate"
                    m = Interpreter(model_path=path, num_threads=1)
                    m.allocate_tensors()
            else:  # pragma: no cover
                raise KeyError(name)
            _models[name] = m
    return m


# ---------------------------------------------------------------------------
# dlib detection and 68 points


def _as_uint8_rgb(image) -> np.ndarray:
    """uint8 contiguous (H, W, 3) RGB from float [0, 1] or uint8 RGB / gray / RGBA."""
    a = np.asarray(image)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in (1, 3, 4) or a.shape[0] < 1 or a.shape[1] < 1:
        raise BadInputError(f"expected an (H, W, 3) RGB image, got an array of shape {a.shape}")
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    elif a.shape[2] == 4:
        a = a[..., :3]
    if a.dtype != np.uint8:
        if not np.issubdtype(a.dtype, np.floating):
            raise BadInputError(f"expected a float image in [0, 1] or a uint8 image, got dtype {a.dtype}")
        if a.size <= 1 << 22:
            a = np.clip(np.nan_to_num(a) * 255.0 + 0.5, 0, 255).astype(np.uint8)
        else:  # in row strips, the same values: no float temporaries of a large image's size
            out = np.empty(a.shape, np.uint8)
            rows = max(1, (1 << 22) // (a.size // a.shape[0]))
            for i in range(0, a.shape[0], rows):
                out[i:i + rows] = np.clip(np.nan_to_num(a[i:i + rows]) * 255.0 + 0.5, 0, 255)
            a = out
    return np.ascontiguousarray(a)


def _rect_box(r) -> tuple[float, float, float, float]:
    return (float(r.left()), float(r.top()), float(r.right()), float(r.bottom()))


def _shape68(img8: np.ndarray, rect) -> np.ndarray:
    s = _model("shape68")(img8, rect)
    return np.array([(p.x, p.y) for p in s.parts()], dtype=np.float64)


def _detect_rects(img8: np.ndarray, upsample: int, detector: str):
    """(dlib.rectangle, score) pairs."""
    if detector == "hog":
        rects, scores, _ = _model("hog").run(img8, upsample, 0.0)
        return list(zip(rects, scores))
    if detector == "cnn":
        return [(d.rect, d.confidence) for d in _model("cnn")(img8, upsample)]
    raise BadInputError(f"unknown face detector {detector!r}: use 'hog' or 'cnn'")


@image_args("image", arrays="keep")
def detect_faces(
    image: ImageLike, *, upsample: int | None = 0, detector: Detector = "hog"
) -> list[Face]:
    """All faces with 68 landmarks, largest box first.

    Parameters
    ----------
    image : str, os.PathLike, PIL.Image.Image or numpy.ndarray
        A file, a PIL image or an (H, W, 3) uint8 / uint16 / float [0, 1] array
        (:func:`facetex.as_image`).
    upsample : int, optional
        Double the image that many times before detecting (finds smaller faces, ~4x slower
        each). None: automatic, search at 1x, and if nothing is found and the longer side is
        at most :data:`AUTO_UPSAMPLE_MAX_SIDE`, again at 2x.
    detector : {"hog", "cnn"}
        dlib's HOG + SVM frontal detector (fast) or its MMOD CNN (more robust to pose,
        ~50x slower on CPU).

    Returns
    -------
    list of Face
        Largest box first; empty when there is no face.

    Raises
    ------
    facetex.BadImageError
        An unreadable file or an unusable array.
    """
    img8 = _as_uint8_rgb(image)
    if upsample is not None and (int(upsample) != upsample or upsample < 0):
        raise BadInputError(f"upsample must be a non-negative integer, got {upsample!r}")
    tries = [int(upsample)] if upsample is not None else [0]
    if upsample is None and max(img8.shape[:2]) <= AUTO_UPSAMPLE_MAX_SIDE:
        tries.append(1)
    found = []
    for n in tries:
        found = _detect_rects(img8, n, detector)
        if found:
            break
    faces = [Face(_rect_box(r), _shape68(img8, r), s) for r, s in found]
    faces.sort(key=lambda f: f.area, reverse=True)
    return faces


@image_args("image", sources={"image": "source"}, arrays="keep")
def detect_face(
    image: ImageLike,
    *,
    face_index: int = 0,
    upsample: int | None = None,
    detector: Detector = "hog",
    source: str | os.PathLike | None = None,
) -> Face:
    """The ``face_index``-th largest face (0 = largest).

    Parameters
    ----------
    image : str, os.PathLike, PIL.Image.Image or numpy.ndarray
        A file, a PIL image or an (H, W, 3) uint8 / uint16 / float [0, 1] array.
    face_index : int
        Which face, by box size (0 = the largest).
    upsample : int, optional
        As in :func:`detect_faces` (None: automatic).
    detector : {"hog", "cnn"}
        As in :func:`detect_faces`.
    source : str or os.PathLike, optional
        The file to name in errors (the path itself when ``image`` is one).

    Returns
    -------
    Face
        Its box, 68 landmarks and detector score.

    Raises
    ------
    facetex.NoFaceError
        No face found (naming ``source``).
    facetex.BadInputError
        ``face_index`` out of range, or an unusable image.
    """
    faces = detect_faces(image, upsample=upsample, detector=detector)
    if not faces:
        raise NoFaceError(
            "no face found; use a frontal photo with the face at least ~80 px wide",
            path=source,
        )
    if not 0 <= face_index < len(faces):
        raise BadInputError(
            f"face index {face_index} is out of range: {len(faces)} face(s) found"
            f" (use 0..{len(faces) - 1})",
            path=source,
        )
    return faces[face_index]


def _checked_box(box: Sequence[float]) -> np.ndarray:
    """A face ``box`` (x0, y0, x1, y1) as 4 float64; BadInputError unless finite with x0 < x1, y0 < y1."""
    b = np.asarray(box, dtype=np.float64).ravel()
    if b.size != 4 or not np.all(np.isfinite(b)) or b[2] <= b[0] or b[3] <= b[1]:
        raise BadInputError(f"a face box must be 4 finite numbers x0 < x1, y0 < y1, got {list(b)}")
    return b


def _dlib_rect(box: Sequence[float]):
    """The dlib.rectangle (rounded to pixels) of a :func:`_checked_box`."""
    import dlib

    return dlib.rectangle(*(int(round(v)) for v in _checked_box(box)))


def landmarks_in_box(image: np.ndarray, box: Sequence[float]) -> np.ndarray:
    """(68, 2) landmarks inside a known face ``box`` (x0, y0, x1, y1), e.g. for tracking video frames."""
    rect = _dlib_rect(box)
    return _shape68(_as_uint8_rgb(image), rect)


# ---------------------------------------------------------------------------
# MediaPipe 468-point face mesh


def _roi_from_points(xy: np.ndarray, right_eye: np.ndarray, left_eye: np.ndarray, scale: float = 1.5):
    """(centre, side, angle) of a rotated square ROI, MediaPipe's rect-to-ROI rule.

    Centre of the axis-aligned bounding box of ``xy``, side = ``scale`` x its
    longer edge, angle = roll of the line from the subject's right eye (image
    left) to the left eye.
    """
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    centre = (lo + hi) / 2
    side = scale * float(max(hi - lo))
    d = left_eye - right_eye
    return centre, side, math.atan2(d[1], d[0])


def _mesh_in_roi(img8: np.ndarray, centre, side, angle):
    """Run the mesh network on a rotated square crop; return ((468, 3) image px, score)."""
    n = MESH_INPUT_SIZE
    k = n / side
    c, s = math.cos(angle), math.sin(angle)
    # image -> crop: q = k R(-angle) (p - centre) + (n - 1) / 2  (pixel centres at integers)
    A = k * np.array([[c, s], [-s, c]])
    t = (n - 1) / 2 - A @ centre
    M = np.hstack([A, t[:, None]])
    crop = cv2.warpAffine(img8, M, (n, n), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    x = (crop.astype(np.float32) / 255.0)[None]
    net = _model("mesh")
    with _lock:  # one interpreter per process; invoke is not re-entrant
        net.set_tensor(net.get_input_details()[0]["index"], x)
        net.invoke()
        out = {d["name"]: net.get_tensor(d["index"]) for d in net.get_output_details()}
    raw = next(v for v in out.values() if v.size == 468 * 3).reshape(468, 3).astype(np.float64)
    logit = float(next(v for v in out.values() if v.size == 1).ravel()[0])
    score = 1.0 / (1.0 + math.exp(-logit))
    # network output is edge-based in [0, n]: pixel-centre coordinate is out - 0.5
    q = raw[:, :2] - 0.5 - (n - 1) / 2
    R = np.array([[c, -s], [s, c]])
    mesh = np.empty((468, 3))
    mesh[:, :2] = centre + (q / k) @ R.T
    mesh[:, 2] = raw[:, 2] / k
    return mesh, score


@image_args("image", sources={"image": "source"}, arrays="keep")
def face_mesh468(
    image: ImageLike,
    face: Face | np.ndarray | None = None,
    *,
    return_score: bool = False,
    min_score: float = MESH_MIN_SCORE,
    source: str | os.PathLike | None = None,
):
    """MediaPipe's 468-point face mesh, (468, 3) float64 (x, y, z) in image pixels.

    Parameters
    ----------
    image : str, os.PathLike, PIL.Image.Image or numpy.ndarray
        A file, a PIL image or an (H, W, 3) uint8 / uint16 / float [0, 1] array.
    face : Face or numpy.ndarray, optional
        The face (or its (68, 2) points) to mesh; default the largest detected.
    return_score : bool
        Also return the network's face-presence probability.
    min_score : float
        Below this presence probability the face counts as not found.
    source : str or os.PathLike, optional
        The file to name in errors (the path itself when ``image`` is one).

    Returns
    -------
    numpy.ndarray or tuple
        (468, 3) float64 (x, y, z); with ``return_score`` ``(mesh, score)``.

    Raises
    ------
    facetex.NoFaceError
        No face, or a presence probability below ``min_score``.

    Notes
    -----
    z is relative depth in the same pixel scale, MediaPipe convention (smaller =
    closer to the camera, roughly zero-mean over the face).
    The crop follows MediaPipe's detection-to-ROI rule: the face box (here the
    68 points' bounding box, which spans brows to chin like BlazeFace's box) made
    square on its longer side, enlarged 1.5x, rotated so the eye line (36 -> 45)
    is level; the mesh is mapped back through the inverse rotation. (Re-cropping
    from the mesh itself, MediaPipe's tracking rule, agreed slightly worse with
    dlib's corners on the samples, so it is not done.) The mesh's outer eye and
    mouth corners (33, 263, 61, 291) lie ~2-3 px (about 3-4 % of the eye distance)
    from dlib's (36, 45, 48, 54) on 400 px portraits, mostly a slight upward
    offset: the two annotation conventions differ.
    """
    img8 = _as_uint8_rgb(image)
    if face is None:
        face = detect_face(img8, source=source)
    p68 = face.points68 if isinstance(face, Face) else _check68(face)
    centre, side, angle = _roi_from_points(p68, p68[36], p68[45], scale=1.5)
    if side < 4:
        raise BadInputError(f"the face is too small for the face mesh ({side:.1f} px ROI)", path=source)
    mesh, score = _mesh_in_roi(img8, centre, side, angle)
    if score < min_score:
        raise NoFaceError(
            f"the face mesh found no face at the given landmarks (score {score:.2f} < {min_score})",
            path=source,
        )
    return (mesh, score) if return_score else mesh
