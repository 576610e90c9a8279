"""Driver motion from a video (Tom Hanks §4, "Dynamic 3D Model").

The paper reconstructs the driver's per-frame 3D flow with Total Moving Face
Reconstruction (its ref. [23]). Substitution: we track MediaPipe's 468-point face
mesh per frame (:func:`facetex.landmarks.face_mesh468`, seeded by dlib's 68
landmarks), which gives a per-vertex 3D position of the same surface points in every
frame. Then:

1. **Rigid part.** Generalized Procrustes (hand-written Umeyama similarity, no
   library does weighted 3D similarity Procrustes) aligns every frame's mesh to the
   driver's mean mesh; each frame's head pose (scale, rotation, translation) is kept
   separately for rendering.
2. **Canonical frame.** The mean mesh is mapped by one similarity onto the canonical
   frontal frame (192 x 240, as the frontalized photos): mesh vertices nearest to the
   dlib fiducials are matched to the driver's mean pose-corrected fiducials (x, y) and
   the generic face's depth (z).
3. **Translation field.** Per frame, the non-rigid residual of every vertex (aligned
   mesh minus mean mesh) is interpolated linearly (fixed Delaunay triangulation of the
   mean mesh) onto the canonical depth-map grid: Δ (H, W, 3) of Tom Hanks §4.
4. **Fiducials.** The 68 dlib points of a frame are lifted onto that frame's mesh
   (barycentric in its 2D projection) and un-posed: expression fiducials in the
   canonical frame, pose removed.
5. **Mouth.** MediaPipe's mesh hardly opens its mouth on small faces: on GRID clips the
   inner-lip gap of its vertices 13/14 follows only ~0.2x the opening of dlib's inner-lip
   landmarks (regression slope; dlib's own tracked opening follows the opening measured on
   720 px upscaled frames with slope 1.0). The un-posed dlib landmarks of every frame
   (``fiducials68``) are therefore kept: the puppet's lips and jaw follow them
   (:meth:`facetex.puppet.puppetry.Puppeteer.grid`, with :class:`LipFields`: two thin-plate
   splines, the upper lip's and the lower lip's with the jaw, joined across the mean mouth
   opening). ``mouth_correction=True`` also corrects the driver's own translation field
   (:class:`MouthCorrection`); off by default: carried through the collection flow onto a
   puppet whose mouth sits elsewhere, its sharp change across the lips tore the puppet's lips.

Lost frames (no face, the mesh network's face score < 0.5, the face partly outside the
frame, dlib's landmarks and the mesh disagreeing, or a squashed/torn landmark shape; see
:data:`LOST_REASONS`) are counted with their reason; their motion is filled by linear
interpolation between the nearest tracked frames (held at the ends) so the series stays
smooth, but the puppet is not drawn on them.
Temporal smoothing: the whole video is available offline, so a zero-lag, zero-phase
Savitzky-Golay filter (window 5 frames, order 2) is run
forwards over the series of aligned meshes, poses and fiducials: it removes
frame-to-frame jitter but keeps a quadratic's peak (fast mouth openings) in place.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .._landmark_fit import (EXPOSED_FACE_LUMA, MIN_EXPOSURE_GAIN, carried_box, exposure_gain,  # noqa: F401
                             fit_landmarks, refit_in_carried_boxes)
from ..errors import FacetexError, NoFaceError
from ._rows import scatter_rows

__all__ = [
    "DriverParams",
    "DriverTrack",
    "track_driver",
    "face_rejection",
    "implausible_shapes",
    "LOST_REASONS",
    "similarity_procrustes",
    "generalized_procrustes",
    "fill_lost",
    "smooth_series",
    "shot_starts",
    "CUT_JUMP",
    "mouth_opening",
    "fit_landmarks",
    "exposure_gain",
    "GridInterpolator",
]

#: iBUG-68 indices of the inner lips (upper 61, 62, 63 over lower 67, 66, 65) and outer eye corners.
_INNER_UPPER = (61, 62, 63)
_INNER_LOWER = (67, 66, 65)
_EYE_OUTER = (36, 45)
#: iBUG-68 points that expressions hardly move (nose bridge and tip, nostrils, eye corners): a cut's test
_RIGID = tuple(range(27, 36)) + (36, 39, 42, 45)
#: a new shot starts where those points move by more than this x the eye-corner distance (median over
#: the points) from one tracked frame to the next: GRID's talking heads move at most 0.022 a frame,
#: the cut between two portraits of one person (FRL London, neutral then smiling) 0.18-0.36
CUT_JUMP = 0.1
#: iBUG-68 points the puppet's mouth follows (:class:`LipFields`): the lips and the lower jaw
_MOUTH_FIDUCIALS = tuple(range(4, 13)) + tuple(range(48, 68))


@dataclass(frozen=True)
class DriverParams:
    """size: canonical frame (W, H); grid_step: depth-map grid step (canonical px) of the
    deformation field; smooth_window / smooth_order: Savitzky-Golay filter over frames (a
    window of 1 disables it); lip_smooth_window: the same filter's window for the lip and jaw
    fiducials the puppet's mouth follows (3 with order 2: unfiltered; a syllable's opening lasts
    3-6 frames at 25 fps, and the 5-frame window cut its peaks: the puppet's mouth opened 0.88
    as far as the driver's on GRID); subspace_frames: frontalized frames kept for the driver's 2D
    average and appearance subspace; min_mesh_score: mesh face score below which a frame is lost;
    redetect_every: frames between face detections (landmarks are tracked in between);
    mouth_correction: lips and jaw of the driver's translation field follow the tracked
    landmarks (module doc, 5; default False: the face mesh alone, the puppet side follows the
    landmarks); landmark_face_px: faces whose box is narrower are upscaled to it before dlib's
    landmarks are fitted (:func:`fit_landmarks`); landmark_refits: fits again in the box carried
    by the frame's own landmarks; landmark_mirror: the last fit averaged with the mirror image's
    (:func:`facetex._landmark_fit.mirror_averaged`), as the persona's photos are read: `facetex bench
    puppet --stress` (60 runs, mirror-read personas), mouth r mean 0.977 -> 0.980, worst 0.923 -> 0.933,
    the other worst runs within 0.01; one more fit a frame (~1.8 ms on a GRID frame)."""

    size: tuple[int, int] = (192, 240)
    grid_step: int = 2
    smooth_window: int = 5
    smooth_order: int = 2
    lip_smooth_window: int = 3
    subspace_frames: int = 24
    min_mesh_score: float = 0.5
    procrustes_iters: int = 3
    redetect_every: int = 10
    mouth_correction: bool = False
    landmark_face_px: float = 200.0
    landmark_refits: int = 1
    landmark_mirror: bool = True


# ---------------------------------------------------------------------------------- maths
def similarity_procrustes(src, dst, weights=None, *, scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R, t) minimising Σ w ||s R src + t − dst||², R a proper rotation (Umeyama 1991).

    ``src``, ``dst`` (N, D). Hand-written: scipy's Rotation.align_vectors has no scale
    and no translation."""
    a = np.asarray(src, np.float64)
    b = np.asarray(dst, np.float64)
    w = np.ones(len(a)) if weights is None else np.asarray(weights, np.float64)
    w = w / w.sum()
    ma, mb = w @ a, w @ b
    ac, bc = a - ma, b - mb
    cov = (bc * w[:, None]).T @ ac
    u, sv, vt = np.linalg.svd(cov)
    d = np.ones(a.shape[1])
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        d[-1] = -1.0
    r = (u * d) @ vt
    var = float(w @ (ac**2).sum(axis=1))
    s = float((sv * d).sum() / var) if scale and var > 0 else 1.0
    return s, r, mb - s * r @ ma


def generalized_procrustes(meshes, *, iters: int = 3):
    """Mean shape of (N, V, 3) meshes under similarity alignment (the first mesh's scale).

    Returns (mean (V, 3), scales (N,), rotations (N, 3, 3), translations (N, 3)) with
    meshes[i] ≈ scales[i] rotations[i] mean + translations[i]."""
    x = np.asarray(meshes, np.float64)
    mean = x[0] - x[0].mean(axis=0)
    ref_size = np.sqrt((mean**2).sum())
    n = len(x)
    s, R, t = np.ones(n), np.tile(np.eye(3), (n, 1, 1)), np.zeros((n, 3))
    for _ in range(max(1, iters)):
        aligned = np.empty_like(x)
        for i in range(n):
            si, ri, ti = similarity_procrustes(x[i], mean)
            aligned[i] = si * x[i] @ ri.T + ti
        mean = aligned.mean(axis=0)
        mean -= mean.mean(axis=0)
        mean *= ref_size / np.sqrt((mean**2).sum())
    for i in range(n):
        s[i], R[i], t[i] = similarity_procrustes(mean, x[i])
    return mean, s, R, t


def fill_lost(series, found, *, segments=None) -> np.ndarray:
    """Copy of a (N, ...) series with the frames where ``found`` is False linearly
    interpolated from the nearest found frames (held constant before the first / after the last).
    ``segments`` (N,) shot ids (:func:`shot_starts`' cumulative sum): each shot is filled from its own
    frames (a shot with none from the whole series)."""
    x = np.asarray(series, np.float64)
    found = np.asarray(found, bool)
    if segments is not None:
        out = fill_lost(x, found)
        for sl in _runs(segments):
            if found[sl].any():
                out[sl] = fill_lost(x[sl], found[sl])
        return out
    if found.all() or not found.any():
        return x.copy()
    idx = np.flatnonzero(found)
    flat = x.reshape(len(x), -1)
    out = np.empty_like(flat)
    frames = np.arange(len(x))
    for k in range(flat.shape[1]):
        out[:, k] = np.interp(frames, idx, flat[idx, k])
    return out.reshape(x.shape)


def _runs(segments) -> list[slice]:
    """The slices of the runs of equal values in ``segments`` (N,)."""
    s = np.asarray(segments)
    edges = np.flatnonzero(np.diff(s) != 0) + 1
    bounds = np.r_[0, edges, len(s)]
    return [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]


def shot_starts(points68, found, *, jump: float = CUT_JUMP) -> np.ndarray:
    """bool (N,): the frames that begin a new shot of an edited clip: the rigid landmarks (nose,
    eye corners) moved by more than ``jump`` x the eye-corner distance (median over the points)
    since the previous tracked frame, the next tracked frame as far from that one and this one as
    far from the one before it (a one-frame slip of the landmarks that comes back is not a cut).
    Frame 0 is never a start. Smoothing the pose and the expression across a cut blended two shots: the frames beside it
    had the next shot's head (a portrait's jaw drawn bulging one frame before the cut)."""
    p = np.asarray(points68, np.float64)
    found = np.asarray(found, bool)
    starts = np.zeros(len(p), bool)
    idx = np.flatnonzero(found)
    if len(idx) < 2:
        return starts
    rigid = list(_RIGID)

    def far(a, b) -> np.ndarray:  # rigid points of b moved from a's by more than the jump
        moved = np.median(np.linalg.norm(p[b][:, rigid] - p[a][:, rigid], axis=2), axis=1)
        return moved > jump * np.maximum(np.linalg.norm(p[a][:, 36] - p[a][:, 45], axis=1), 1e-9)

    cut = far(idx[:-1], idx[1:])
    two = far(idx[:-2], idx[2:])
    cut[:-1] &= two  # still away one frame later
    cut[1:] &= two  # and away from the frame before too (not the return from a slip)
    starts[idx[1:][cut]] = True
    return starts


def smooth_series(series, window: int = 5, order: int = 2, *, segments=None) -> np.ndarray:
    """Zero-phase Savitzky-Golay smoothing of a (N, ...) series along frames; the ends are
    fitted by one polynomial over the first/last window (scipy's ``mode="interp"``). ``segments``
    (N,) shot ids: each shot smoothed on its own (:func:`shot_starts`).

    Written with numpy (a least-squares polynomial per window) because importing
    ``scipy.signal`` costs ~2 s here (it loads scipy.stats); tested against
    ``scipy.signal.savgol_filter``."""
    x = np.asarray(series, np.float64)
    if segments is not None:
        out = x.copy()
        for sl in _runs(segments):
            out[sl] = smooth_series(x[sl], window, order)
        return out
    n = len(x)
    w = min(int(window), n)
    w -= 1 - w % 2  # an odd window, centred on its frame
    if w < 3 or w <= order:
        return x.copy()
    half = w // 2
    V = np.vander(np.arange(-half, half + 1, dtype=np.float64), order + 1, increasing=True)  # (w, order + 1)
    P = np.linalg.pinv(V)  # polynomial coefficients from w samples; P[0]: the value at the centre
    flat = x.reshape(n, -1)
    out = np.zeros_like(flat)
    for j in range(w):
        out[half:n - half] += P[0, j] * flat[j:n - w + 1 + j]
    out[:half] = V[:half] @ (P @ flat[:w])
    out[n - half:] = V[half + 1:] @ (P @ flat[n - w:])
    return out.reshape(x.shape)


def mouth_opening(points68) -> np.ndarray:
    """Inner-lip opening over inter-ocular (outer eye corner) distance, per face: (...,) for (..., 68, 2)."""
    p = np.asarray(points68, np.float64)
    gap = np.linalg.norm(p[..., _INNER_UPPER, :] - p[..., _INNER_LOWER, :], axis=-1).mean(axis=-1)
    iod = np.linalg.norm(p[..., _EYE_OUTER[0], :] - p[..., _EYE_OUTER[1], :], axis=-1)
    return gap / np.maximum(iod, 1e-9)


class GridInterpolator:
    """Piecewise-linear interpolation of per-vertex values onto a pixel grid (fixed
    Delaunay triangulation of the vertices' (x, y); scipy.spatial.Delaunay). Grid pixels
    outside the triangulation are invalid (``mask`` False) and get 0."""

    def __init__(self, xy, grid_xy):
        from scipy.spatial import Delaunay

        tri = Delaunay(np.asarray(xy, np.float64))
        g = np.asarray(grid_xy, np.float64)
        self.shape = g.shape[:-1]
        pts = g.reshape(-1, 2)
        simplex = tri.find_simplex(pts)
        self.mask = (simplex >= 0).reshape(self.shape)
        inside = simplex >= 0
        s = simplex[inside]
        trans = tri.transform[s]
        b = np.einsum("nij,nj->ni", trans[:, :2], pts[inside] - trans[:, 2])
        self.weights = np.c_[b, 1 - b.sum(axis=1)]
        self.vertices = tri.simplices[s]
        self.flat = np.flatnonzero(inside)

    def __call__(self, values) -> np.ndarray:
        v = np.asarray(values, np.float64)
        out = np.zeros((int(np.prod(self.shape)),) + v.shape[1:])
        # np.take and scatter_rows: fancy indexing of short rows is slow
        res = np.einsum("nk,nk...->n...", self.weights, v.take(self.vertices, axis=0))
        if out.ndim == 2:
            scatter_rows(out, self.flat, res)
        else:
            out[self.flat] = res
        return out.reshape(self.shape + v.shape[1:])


# ------------------------------------------------------------------------------ tracking
@dataclass(eq=False)
class DriverTrack:
    """Raw per-frame tracking of a driver video (N frames).

    points68 (N, 68, 2) and mesh (N, 468, 3) in image pixels (NaN where lost); found (N,)
    bool; score (N,) mesh face score; frontal (K, H, W, 3) float32 frontalized frames (none when
    tracked without frontal images) and frontal_points68 (K, 68, 2) their pose-corrected
    landmarks (every ``stride``-th tracked frame, K <= subspace_frames); frame_size (W, H); fps; path; lost_reason (N,) why each
    lost frame was rejected ("" where found; see :data:`LOST_REASONS`); rims: the thin lines of those
    frames averaged in the face's frame (:func:`~facetex.geometry.glasses.rim_template`; the driver's
    glasses stay in front of the puppet) or None."""

    points68: np.ndarray
    mesh: np.ndarray
    found: np.ndarray
    score: np.ndarray
    frontal: np.ndarray
    frontal_points68: np.ndarray
    frame_size: tuple[int, int]
    fps: float
    path: str
    has_audio: bool = False
    lost_reason: list | None = None
    rims: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return len(self.found)

    @property
    def lost_causes(self) -> dict:
        """{reason: number of frames} of the lost frames."""
        out: dict = {}
        for i in np.flatnonzero(~self.found):
            r = (self.lost_reason[i] if self.lost_reason else "") or "no face"
            out[r] = out.get(r, 0) + 1
        return out

    @property
    def n_lost(self) -> int:
        return int((~self.found).sum())


#: Why a tracked face is rejected (the frame then counts as lost).
LOST_REASONS = {
    "no face": "no face found (or the face mesh's face score < min_mesh_score)",
    "partly outside the frame": "more than 3 % of the face mesh or an inner landmark lies outside the frame",
    "landmarks disagree": "dlib's eye/mouth corners and the face mesh's differ by > 12 % of the eye distance",
    "implausible shape": "the 68 points differ from the clip's mean shape (similarity-aligned) by > "
                         "max(8 %, 4 x the median) of the eye distance (squashed or torn landmarks)",
}
#: corresponding dlib and MediaPipe points: outer eye corners and mouth corners
_DLIB_CORNERS, _MESH_CORNERS = (36, 45, 48, 54), (33, 263, 61, 291)


def face_rejection(points68: np.ndarray, mesh: np.ndarray, frame_size, *, min_inside: float = 0.97,
                   max_disagreement: float = 0.12) -> str:
    """Why a tracked face is not usable ("" if it is): part of it outside the frame, or dlib's
    landmarks and the face mesh telling different stories (both networks guess when the face
    is cut off: the landmarks get squashed against the border). See :data:`LOST_REASONS`."""
    p = np.asarray(points68, np.float64)
    m = np.asarray(mesh, np.float64)
    w, h = frame_size

    def inside(q):
        return (q[:, 0] >= -0.5) & (q[:, 0] <= w - 0.5) & (q[:, 1] >= -0.5) & (q[:, 1] <= h - 0.5)

    if inside(m[:, :2]).mean() < min_inside or not inside(p[17:]).all():
        return "partly outside the frame"
    iod = float(np.linalg.norm(p[36] - p[45]))
    d = np.linalg.norm(m[list(_MESH_CORNERS), :2] - p[list(_DLIB_CORNERS)], axis=1).mean()
    if not iod > 0 or d > max_disagreement * iod:
        return "landmarks disagree"
    return ""


def implausible_shapes(points68: np.ndarray, found: np.ndarray, *, floor: float = 0.08,
                       factor: float = 4.0) -> np.ndarray:
    """bool (N,): found frames whose 68 points, similarity-aligned to the clip's mean shape,
    differ from it by more than max(``floor``, ``factor`` x the median) of the mean eye-corner
    distance (mean point distance)."""
    bad = np.zeros(len(found), bool)
    idx = np.flatnonzero(found)
    if len(idx) < 3:
        return bad
    P = np.asarray(points68, np.float64)
    mean = P[idx].mean(axis=0)
    iod = float(np.linalg.norm(mean[36] - mean[45]))
    res = np.empty(len(idx))
    for k, i in enumerate(idx):
        sc, R, t = similarity_procrustes(P[i], mean)
        res[k] = np.linalg.norm(sc * P[i] @ R.T + t - mean, axis=1).mean() / max(iod, 1e-9)
    bad[idx] = res > max(floor, factor * float(np.median(res)))
    return bad


def _track_frame(frame, prev, params: DriverParams, detect: bool):
    """(points68, mesh, score, anchor) of the face in one frame, or None when it is lost.

    ``prev``: (points68, anchor) of the previous frame or None; anchor = (detector box, the
    landmarks found in it). Between detections (every ``redetect_every`` frames, and whenever
    the face was lost) the landmarks are re-fitted in the detector box carried along by the
    landmarks' motion (dlib's predictor expects detector boxes); the mesh score checks them."""
    from ..landmarks import detect_faces, face_mesh468

    def carried(anchor):
        return refit_in_carried_boxes(frame, prev[0], *anchor, times=1 + params.landmark_refits,
                                      face_px=params.landmark_face_px, mirror=params.landmark_mirror)

    cands = []  # (points68, anchor)
    if prev is not None and not detect:
        cands.append((carried(prev[1]), prev[1]))
    else:
        faces = detect_faces(frame, upsample=0)
        if not faces and max(frame.shape[:2]) <= 640:
            faces = detect_faces(frame, upsample=1)
        if faces:
            if prev is not None and len(faces) > 1:  # keep following the same person
                c = prev[0].mean(axis=0)
                faces = sorted(faces, key=lambda f: np.hypot(*(f.points68.mean(axis=0) - c)))
            box = tuple(faces[0].box)
            p = fit_landmarks(frame, box, face_px=params.landmark_face_px, points68=faces[0].points68,
                              mirror=params.landmark_mirror)
            cands.append((p, (box, p)))
        elif prev is not None:  # detector miss: landmarks in the carried box, checked by the mesh score
            cands.append((carried(prev[1]), prev[1]))
    for p68, anchor in cands:
        try:
            mesh, score = face_mesh468(frame, p68, return_score=True, min_score=0.0)
        except FacetexError:
            continue
        if score >= params.min_mesh_score:
            return p68, mesh, score, anchor
    return None


#: Driver frames with a longer side above this are scaled down to it as they are decoded (an 8K
#: frame is 100 MB as RGB): the driver is tracked and shown at that size (issue 23).
DRIVER_MAX_SIDE = 1920


def track_driver(path, *, max_frames: int | None = None, params: DriverParams = DriverParams(),
                 progress: Callable | None = None, frontal_images: bool = True) -> DriverTrack:
    """Track the face through a driver video (first pass). NoFaceError naming the file
    when no frame has a face. Without ``frontal_images`` only the sampled frames'
    pose-corrected landmarks are kept (``frontal`` is empty): enough for the landmark
    correspondence, and the frontalization's sampling and symmetry fill are skipped."""
    from ..geometry.frontalize import frontalize, pose_corrected_points68
    from ..geometry.glasses import rim_response, rim_template
    from ..io import iter_video_frames, video_info

    def frontal_sample(frame, p68) -> tuple[np.ndarray | None, np.ndarray]:
        """(frontalized image, or None without frontal images; pose-corrected landmarks)."""
        if frontal_images:
            fr = frontalize(frame.astype(np.float32) / 255.0, p68, size=params.size)
            return fr.image, fr.points68
        return None, pose_corrected_points68(frame.shape, p68, size=params.size)

    path = Path(path)
    info = video_info(path)
    n_est = info["n_frames"] if max_frames is None else min(info["n_frames"], int(max_frames))
    stride = max(1, int(math.ceil(max(n_est, 1) / params.subspace_frames)))
    p68s, meshes, found, scores, frontal, frontal_p, frontal_i, reasons = [], [], [], [], [], [], [], []
    rim_maps = []
    prev = None
    size = None
    last_detect = -(10**9)
    # uint8 frames: dlib and the mesh network take them as they are (no conversion per call)
    frames = iter_video_frames(path, max_frames=max_frames, uint8=True, max_side=DRIVER_MAX_SIDE)
    for i, frame in enumerate(frames):
        size = (frame.shape[1], frame.shape[0])
        detect = prev is None or i - last_detect >= params.redetect_every
        last_detect = i if detect else last_detect
        r = _track_frame(frame, prev, params, detect)
        why = "no face" if r is None else face_rejection(r[0], r[1], size)
        if why:
            p68s.append(np.full((68, 2), np.nan))
            meshes.append(np.full((468, 3), np.nan))
            found.append(False)
            scores.append(0.0 if r is None else r[2])
            reasons.append(why)
            prev = None
        else:
            p68, mesh, score, anchor = r
            prev = (p68, anchor)
            p68s.append(p68)
            meshes.append(mesh)
            found.append(True)
            scores.append(score)
            reasons.append("")
            if i % stride == 0 and len(frontal_p) < params.subspace_frames:
                rim_maps.append((i, rim_response(frame, p68)))
                try:
                    img, pts = frontal_sample(frame, p68)
                    frontal_p.append(pts)
                    frontal_i.append(i)
                    if img is not None:
                        frontal.append(img)
                except FacetexError:
                    pass
        if progress:
            progress(n=1, stage="track", lost=len(found) - int(sum(found)))
    found_a = np.array(found, bool)
    p68a, mesha = np.array(p68s).reshape(-1, 68, 2), np.array(meshes).reshape(-1, 468, 3)
    if found_a.any():  # whole-clip check: torn or squashed landmarks
        bad = implausible_shapes(p68a, found_a)
        for i in np.flatnonzero(bad):
            found_a[i], reasons[i] = False, "implausible shape"
            p68a[i], mesha[i] = np.nan, np.nan
        keep = [k for k, i in enumerate(frontal_i) if found_a[i]]
        frontal_p = [frontal_p[k] for k in keep]
        frontal = [frontal[k] for k in keep] if frontal_images else []
    if not found_a.any():
        why = max(set(reasons), key=reasons.count) if reasons else "no face"
        hint = {"partly outside the frame": "the face is never whole inside the frame"}.get(why, why)
        raise NoFaceError(f"no usable face in any frame of the driver video ({hint}): use a video showing one "
                          "face frontally, at least ~80 px wide", path=path)
    if not frontal_p:  # every sampled frame failed to frontalize: take any tracked one
        j = int(np.flatnonzero(found_a)[0])
        frames = iter_video_frames(path, max_frames=j + 1, uint8=True, max_side=DRIVER_MAX_SIDE)
        frame = next(f for k, f in enumerate(frames) if k == j)
        img, pts = frontal_sample(frame, p68a[j])
        frontal, frontal_p = ([] if img is None else [img]), [pts]
    W, H = params.size
    return DriverTrack(
        points68=p68a, mesh=mesha, found=found_a, score=np.array(scores),
        frontal=np.array(frontal, np.float32).reshape(-1, H, W, 3), frontal_points68=np.array(frontal_p),
        frame_size=size, fps=float(info["fps"]) or 25.0, path=str(path), has_audio=bool(info["has_audio"]),
        lost_reason=reasons, rims=rim_template([r for i, r in rim_maps if found_a[i]]))


