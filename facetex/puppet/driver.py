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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import FacetexError, NoFaceError
from ._rows import scatter_rows

__all__ = [
    "DriverParams",
    "DriverTrack",
    "DriverMotion",
    "track_driver",
    "driver_motion",
    "face_rejection",
    "implausible_shapes",
    "LOST_REASONS",
    "similarity_procrustes",
    "generalized_procrustes",
    "fill_lost",
    "smooth_series",
    "mouth_opening",
    "GridInterpolator",
    "LipFields",
    "BrowFields",
    "brow_heights",
    "LidFields",
    "eye_openness",
    "unfold_columns",
    "MouthCorrection",
]

#: iBUG-68 indices of the inner lips (upper 61, 62, 63 over lower 67, 66, 65) and outer eye corners.
_INNER_UPPER = (61, 62, 63)
_INNER_LOWER = (67, 66, 65)
_EYE_OUTER = (36, 45)
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
    landmarks)."""

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


def fill_lost(series, found) -> np.ndarray:
    """Copy of a (N, ...) series with the frames where ``found`` is False linearly
    interpolated from the nearest found frames (held constant before the first / after the last)."""
    x = np.asarray(series, np.float64)
    found = np.asarray(found, bool)
    if found.all() or not found.any():
        return x.copy()
    idx = np.flatnonzero(found)
    flat = x.reshape(len(x), -1)
    out = np.empty_like(flat)
    frames = np.arange(len(x))
    for k in range(flat.shape[1]):
        out[:, k] = np.interp(frames, idx, flat[idx, k])
    return out.reshape(x.shape)


def smooth_series(series, window: int = 5, order: int = 2) -> np.ndarray:
    """Zero-phase Savitzky-Golay smoothing of a (N, ...) series along frames; the ends are
    fitted by one polynomial over the first/last window (scipy's ``mode="interp"``).

    Written with numpy (a least-squares polynomial per window) because importing
    ``scipy.signal`` costs ~2 s here (it loads scipy.stats); tested against
    ``scipy.signal.savgol_filter``."""
    x = np.asarray(series, np.float64)
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
    lost frame was rejected ("" where found; see :data:`LOST_REASONS`)."""

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


def _box_of(points68: np.ndarray, ref_box, ref_points: np.ndarray):
    """The detector box ``ref_box`` (found with ``ref_points``) moved and scaled with the landmarks."""
    c0, c1 = ref_points.mean(axis=0), points68.mean(axis=0)
    k = float(np.ptp(points68, axis=0).max() / max(np.ptp(ref_points, axis=0).max(), 1e-6))
    bc = np.array([(ref_box[0] + ref_box[2]) / 2, (ref_box[1] + ref_box[3]) / 2])
    half = np.array([ref_box[2] - ref_box[0], ref_box[3] - ref_box[1]]) * k / 2
    c = c1 + (bc - c0) * k
    return (c[0] - half[0], c[1] - half[1], c[0] + half[0], c[1] + half[1])


def _track_frame(frame, prev, params: DriverParams, detect: bool):
    """(points68, mesh, score, anchor) of the face in one frame, or None when it is lost.

    ``prev``: (points68, anchor) of the previous frame or None; anchor = (detector box, the
    landmarks found in it). Between detections (every ``redetect_every`` frames, and whenever
    the face was lost) the landmarks are re-fitted in the detector box carried along by the
    landmarks' motion (dlib's predictor expects detector boxes); the mesh score checks them."""
    from ..landmarks import detect_faces, face_mesh468, landmarks_in_box

    cands = []  # (points68, anchor)
    if prev is not None and not detect:
        box = _box_of(prev[0], *prev[1])
        cands.append((landmarks_in_box(frame, box), prev[1]))
    else:
        faces = detect_faces(frame, upsample=0)
        if not faces and max(frame.shape[:2]) <= 640:
            faces = detect_faces(frame, upsample=1)
        if faces:
            if prev is not None and len(faces) > 1:  # keep following the same person
                c = prev[0].mean(axis=0)
                faces = sorted(faces, key=lambda f: np.hypot(*(f.points68.mean(axis=0) - c)))
            cands.append((faces[0].points68, (tuple(faces[0].box), faces[0].points68)))
        elif prev is not None:  # detector miss: landmarks in the carried box, checked by the mesh score
            box = _box_of(prev[0], *prev[1])
            cands.append((landmarks_in_box(frame, box), prev[1]))
    for p68, anchor in cands:
        try:
            mesh, score = face_mesh468(frame, p68, return_score=True, min_score=0.0)
        except FacetexError:
            continue
        if score >= params.min_mesh_score:
            return p68, mesh, score, anchor
    return None


def track_driver(path, *, max_frames: int | None = None, params: DriverParams = DriverParams(),
                 progress: Callable | None = None, frontal_images: bool = True) -> DriverTrack:
    """Track the face through a driver video (first pass). NoFaceError naming the file
    when no frame has a face. Without ``frontal_images`` only the sampled frames'
    pose-corrected landmarks are kept (``frontal`` is empty): enough for the landmark
    correspondence, and the frontalization's sampling and symmetry fill are skipped."""
    from ..geometry.frontalize import frontalize, pose_corrected_points68
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
    prev = None
    size = None
    last_detect = -(10**9)
    # uint8 frames: dlib and the mesh network take them as they are (no conversion per call)
    for i, frame in enumerate(iter_video_frames(path, max_frames=max_frames, uint8=True)):
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
        frame = next(f for k, f in enumerate(iter_video_frames(path, max_frames=j + 1, uint8=True)) if k == j)
        img, pts = frontal_sample(frame, p68a[j])
        frontal, frontal_p = ([] if img is None else [img]), [pts]
    W, H = params.size
    return DriverTrack(
        points68=p68a, mesh=mesha, found=found_a, score=np.array(scores),
        frontal=np.array(frontal, np.float32).reshape(-1, H, W, 3), frontal_points68=np.array(frontal_p),
        frame_size=size, fps=float(info["fps"]) or 25.0, path=str(path), has_audio=bool(info["has_audio"]),
        lost_reason=reasons)


# ------------------------------------------------------------------------------- motion
@dataclass(eq=False)
class DriverMotion:
    """The driver's motion in the canonical frame (N frames, canonical W x H, grid h x w).

    pose_A (N, 3, 3), pose_b (N, 3): head pose, image pixel = A X + b for a canonical point
    X = (x, y, z) (A = scale x rotation; orthographic image x, y; z for depth order);
    mean_mesh (468, 3) canonical; deltas (N, 468, 3) canonical per-vertex residuals;
    fiducials (N, 49, 2) canonical expression fiducials, mean_fiducials (49, 2);
    grid: :class:`GridInterpolator` onto the depth-map grid, grid_mesh (h, w, 3) the mean
    mesh on it (NaN outside), grid_step; found (N,) as tracked; opening (N,) mouth opening
    of the (filled, unsmoothed) tracked landmarks; frontal_mean68 (68, 2): the mean frontalized
    landmarks the canonical frame is fitted to."""

    pose_A: np.ndarray
    pose_b: np.ndarray
    mean_mesh: np.ndarray
    deltas: np.ndarray
    fiducials: np.ndarray
    mean_fiducials: np.ndarray
    grid: GridInterpolator
    grid_mesh: np.ndarray
    grid_step: int
    found: np.ndarray
    opening: np.ndarray
    points68: np.ndarray
    anchors: np.ndarray = field(repr=False, default=None)
    mouth: "MouthCorrection | None" = field(repr=False, default=None)
    fiducials68: np.ndarray | None = field(repr=False, default=None)
    triangles: np.ndarray | None = field(repr=False, default=None)
    frontal_mean68: np.ndarray | None = field(repr=False, default=None)

    def __len__(self) -> int:
        return len(self.found)

    def delta_field(self, i: int) -> np.ndarray:
        """Δ_i (h, w, 3): M_D^i − M̄_D on the driver's depth-map grid (Tom Hanks §4), the
        lips and jaw following the tracked landmarks (:class:`MouthCorrection`)."""
        d = self.grid(self.deltas[i])
        if self.mouth is not None:
            d[..., :2] += self.mouth(i) * self.grid.mask[..., None]
        return d

    @property
    def iod(self) -> float:
        """Eye-centre distance of the mean fiducials (canonical px)."""
        return _iod49(self.mean_fiducials)


#: iBUG-68 points whose motion the mouth correction follows (outer/inner lips; jaw 5-11 move with the
#: lower lip) and points held still by it (brows, nose, eyes; the upper jaw near the ears).
_UPPER_LIP = (48, 49, 50, 51, 52, 53, 54, 60, 61, 62, 63, 64)
_LOWER_LIP = (48, 54, 55, 56, 57, 58, 59, 60, 64, 65, 66, 67, 5, 6, 7, 8, 9, 10, 11)
_UPPER_STILL = tuple(range(17, 48))
_LOWER_STILL = (0, 1, 2, 14, 15, 16, 31, 32, 33, 34, 35)


def _increasing(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) sorted by x with repeated x merged (for np.interp)."""
    order = np.argsort(x, kind="stable")
    xs, ys = x[order], y[order]
    keep = np.r_[True, np.diff(xs) > 1e-9]
    return xs[keep], ys[keep]


def _upper_lower_field(fields, motion68) -> np.ndarray:
    """(h, w, 2) motion of a :class:`LipFields` / :class:`LidFields`: the upper and lower
    landmarks' fields mixed by each grid point's ``side`` (0 upper, 1 lower)."""
    (mu, ou), (ml, ol) = fields.upper, fields.lower
    r = np.asarray(motion68, np.float32)
    up, lo = ou @ r[mu], ol @ r[ml]
    out = np.empty(up.shape, np.float32)
    for c in range(2):  # per column: numpy broadcasts over a length-2 axis slowly
        out[:, c] = up[:, c] + fields.side * (lo[:, c] - up[:, c])
    return out.reshape(fields.shape + (2,))


class LipFields:
    """Thin-plate-spline fields of lip and jaw motion on a grid, split at the mouth.

    ``mean68`` (68, 2) the face's mean landmarks, ``grid_xy`` (h, w, 2) grid positions (same
    frame). :meth:`__call__` takes motions (68, 2) of the landmarks (only the lip and jaw ones
    are read; brows, eyes, nose and the upper jaw are held still) and returns the (h, w, 2)
    field: the upper lip's spline down to the upper inner-lip contour, the lower lip's (with
    the jaw) from the lower inner-lip contour down, and between the two contours (the mouth
    opening of the mean face) a linear blend across the opening, so the lips part or close
    without the opening folding over them. Beyond the mouth corners the two blend smoothly.
    The splines' linear operators (scipy RBFInterpolator on an identity) are computed once; a
    call is two small matrix products.
    """

    def __init__(self, mean68: np.ndarray, grid_xy: np.ndarray, smoothing: float = 1.0):
        from scipy.interpolate import RBFInterpolator

        p = np.asarray(mean68, np.float64)
        self.shape = grid_xy.shape[:2]
        g = np.asarray(grid_xy, np.float64).reshape(-1, 2)
        ops = []
        for moving, still in ((_UPPER_LIP, _UPPER_STILL), (_LOWER_LIP, _LOWER_STILL)):
            idx = list(moving) + list(still)
            rbf = RBFInterpolator(p[idx], np.eye(len(idx)), kernel="thin_plate_spline", smoothing=smoothing)
            op = rbf(g)[:, : len(moving)]  # still points move by 0: their columns drop out
            ops.append((np.asarray(moving), op.astype(np.float32)))
        self.upper, self.lower = ops
        # weight of the lower field: 0 above the upper inner lip, 1 below the lower one, linear across
        # the opening between them; beyond the outer mouth corners a sigmoid about the mid line
        # that widens with the distance from the corner
        up, lo = (48, 60, 61, 62, 63, 64, 54), (48, 60, 67, 66, 65, 64, 54)
        ux, uy = p[list(up), 0], p[list(up), 1]
        lx, ly = p[list(lo), 0], p[list(lo), 1]
        x, y = g[:, 0], g[:, 1]
        y_up = np.interp(x, *_increasing(ux, uy))
        y_lo = np.interp(x, *_increasing(lx, ly))
        band = np.maximum(y_lo - y_up, 0.5)
        inside = np.clip((y - y_up) / band, 0.0, 1.0)
        mid = (y_up + y_lo) / 2
        outside = np.maximum(0.0, np.maximum(p[48, 0] - x, x - p[54, 0]))
        width = 0.3 + 0.5 * outside
        sig = 1.0 / (1.0 + np.exp(-np.clip((y - mid) / width, -50, 50)))
        self.side = np.where(outside > 0, sig, inside).astype(np.float32)

    def __call__(self, motion68) -> np.ndarray:
        return _upper_lower_field(self, motion68)


#: iBUG-68 brow points (right 17-21, left 22-26)
BROWS = tuple(range(17, 27))


class BrowFields:
    """Thin-plate-spline field of brow motion on a grid.

    ``mean68`` (68, 2) the face's mean landmarks, ``grid_xy`` (h, w, 2) grid positions (same
    frame). :meth:`__call__` takes motions (68, 2) of the landmarks (only the brows 17-26 are
    read) and returns the (h, w, 2) field that moves the brows by them while the eyes, nose, jaw
    and lips stay (the skin between brow and lid stretches) and the forehead fades back to still
    at ``forehead`` x the eye-centre distance above the brows (no landmark there: a spline held
    only below the brows would carry the whole forehead and hairline with them). As
    :class:`LipFields`, the spline's linear operator is computed once; a call is one product.
    """

    def __init__(self, mean68: np.ndarray, grid_xy: np.ndarray, smoothing: float = 1.0, forehead: float = 0.6):
        from scipy.interpolate import RBFInterpolator

        p = np.asarray(mean68, np.float64)
        self.shape = grid_xy.shape[:2]
        g = np.asarray(grid_xy, np.float64).reshape(-1, 2)
        iod = float(np.linalg.norm(p[36:42].mean(axis=0) - p[42:48].mean(axis=0)))
        still = np.delete(p, list(BROWS), axis=0)
        top = p[list(BROWS)] - [0.0, forehead * iod]
        ctrl = np.concatenate([p[list(BROWS)], still, top])
        rbf = RBFInterpolator(ctrl, np.eye(len(ctrl)), kernel="thin_plate_spline", smoothing=smoothing)
        self.op = np.ascontiguousarray(rbf(g)[:, : len(BROWS)], np.float32)

    def __call__(self, motion68) -> np.ndarray:
        r = np.asarray(motion68, np.float32)[list(BROWS)]
        return (self.op @ r).reshape(self.shape + (2,))


def brow_heights(points68) -> np.ndarray:
    """Heights (..., 10) of the brow points 17-26 above the line through the eye centres, over the
    eye-centre distance (positive: above), for (..., 68, 2) landmarks (image y down)."""
    p = np.asarray(points68, np.float64)
    a, b = p[..., 36:42, :].mean(axis=-2), p[..., 42:48, :].mean(axis=-2)
    e = b - a
    iod = np.maximum(np.linalg.norm(e, axis=-1, keepdims=True), 1e-9)
    n = np.stack([e[..., 1], -e[..., 0]], axis=-1) / iod  # unit normal pointing up (y down)
    d = p[..., 17:27, :] - ((a + b) / 2)[..., None, :]
    return (d * n[..., None, :]).sum(axis=-1) / iod


def unfold_columns(grid: np.ndarray, mask: np.ndarray, min_spacing: float = 0.1) -> np.ndarray:
    """The grid mesh (h, w, 3) with the y of its vertices made increasing down every column, rows
    at least ``min_spacing`` x the median row step apart (``mask`` (h, w): the valid vertices;
    x and z unchanged).

    Closing a puppet's lips squeezes the band between its inner-lip contours; where the driver's
    landmarks close further than that band (they meet or cross), the lower lip's rows pass above
    the upper lip's: the grid folds over, and the z-buffer then shows whichever sheet is nearer,
    cut along the grid's triangles (a stair-stepped lip line of grid-cell steps). The fix moves
    both sides of a fold to meet: the mean of the smallest increasing sequence above (a running
    maximum from the top) and the largest below (a running minimum from the bottom), so the
    lips meet in the middle and the squeezed band stays a thin line. A no-op where the grid
    does not fold."""
    g = np.array(grid, np.float64, copy=True)
    m = np.asarray(mask, bool) & np.isfinite(g[..., 1])
    if not m.any():
        return g
    h = g.shape[0]
    ys = np.where(m, g[..., 1], np.nan)
    d = np.diff(ys, axis=0)
    # np.median of the non-NaN values: np.nanmedian's value, without its overhead
    step = float(np.median(d[~np.isnan(d)])) if np.isfinite(d).any() else 1.0
    off = min_spacing * step * np.arange(h, dtype=np.float64)[:, None]
    z = ys - off
    top = np.maximum.accumulate(np.where(m, z, -np.inf), axis=0)
    bottom = np.minimum.accumulate(np.where(m, z, np.inf)[::-1], axis=0)[::-1]
    with np.errstate(invalid="ignore"):  # +-inf above/below a column's valid rows; never used
        fixed = np.where(top == bottom, ys, 0.5 * (top + bottom) + off)  # untouched where no fold
    g[..., 1] = np.where(m, fixed, g[..., 1])
    return g


class MouthCorrection:
    """Lip and jaw correction of the translation field from the tracked landmarks (module doc, 5).

    ``fid68`` (N, 68, 2) un-posed canonical landmarks per frame, ``mesh_at`` (N, 68, 2) the
    mesh's translation field at their mean positions, ``grid_xy`` (h, w, 2) canonical grid
    positions. Frame i's correction is the :class:`LipFields` field of the residual
    r = (F_i − F̄) − Δ_mesh,i(F̄).
    """

    def __init__(self, fid68: np.ndarray, mesh_at: np.ndarray, found: np.ndarray, grid_xy: np.ndarray,
                 smoothing: float = 1.0):
        mean = fid68[found].mean(axis=0)
        self.fields = LipFields(mean, grid_xy, smoothing)
        self.residual = (fid68 - mean) - mesh_at  # (N, 68, 2)

    def __call__(self, i: int) -> np.ndarray:
        """(h, w, 2) correction of frame i's translation field (canonical px, x and y)."""
        return self.fields(self.residual[i])


def _iod49(f49: np.ndarray) -> float:
    # 49-point layout: right eye 19..24, left eye 25..30 (iBUG 36..41, 42..47)
    return float(np.linalg.norm(f49[19:25].mean(axis=0) - f49[25:31].mean(axis=0)))


def _anchor_vertices(points68: np.ndarray, mesh: np.ndarray, found: np.ndarray) -> np.ndarray:
    """For each iBUG point, the mesh vertex nearest to it in 2D on average over the tracked frames."""
    p = points68[found]
    m = mesh[found, :, :2]
    step = max(1, len(p) // 30)
    diff = p[::step, :, None, :] - m[::step, None, :, :]
    d = np.sqrt(diff[..., 0] ** 2 + diff[..., 1] ** 2).mean(axis=0)  # (68, 468); norm's reduce over 2 is slow
    return d.argmin(axis=1)


def _barycentrics(points: np.ndarray, a: np.ndarray, e1: np.ndarray, e2: np.ndarray, det: np.ndarray):
    """(l0, l1, l2) of points (..., 2) in triangles given corner a, edges e1, e2 (broadcast)."""
    d = points - a[..., :2]
    l1 = (d[..., 0] * e2[..., 1] - d[..., 1] * e2[..., 0]) / det
    l2 = (e1[..., 0] * d[..., 1] - e1[..., 1] * d[..., 0]) / det
    return 1.0 - l1 - l2, l1, l2


def _lift_points(points: np.ndarray, mesh: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(P, 3) positions on a (468, 3) mesh of (P, 2) image points: barycentric in the mesh
    triangle (of the fixed triangulation ``triangles``) containing the point in 2D (the one it
    is deepest inside where triangles overlap, the lowest index on ties), or the nearest one
    (barycentrics clamped) outside the mesh.

    Only the triangles near enough to contain a point are tried (centroid within the
    triangle's largest centroid-to-corner distance); points inside none of them try all
    triangles: the same triangle as a search over all of them, ~4x faster."""
    a, b, c = (mesh[triangles[:, k]] for k in range(3))
    e1, e2 = b[:, :2] - a[:, :2], c[:, :2] - a[:, :2]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    det = np.where(np.abs(det) < 1e-12, 1e-12, det)
    cen = (a[:, :2] + b[:, :2] + c[:, :2]) / 3.0
    reach = np.max([np.sum((v[:, :2] - cen) ** 2, axis=1) for v in (a, b, c)], axis=0)  # squared
    P = len(points)
    dist = (points[:, 0, None] - cen[:, 0]) ** 2 + (points[:, 1, None] - cen[:, 1]) ** 2  # (P, T)
    pi, ti = np.nonzero(dist <= reach)  # pairs sorted by point, then triangle
    l0, l1, l2 = _barycentrics(points[pi], a[ti], e1[ti], e2[ti], det[ti])
    depth = np.minimum(np.minimum(l0, l1), l2)
    order = np.lexsort((ti, -depth, pi))  # per point: deepest first, lowest index on ties
    first = order[np.r_[True, pi[order][1:] != pi[order][:-1]]] if order.size else order
    best = np.zeros(P, np.int64)
    lam = np.zeros((P, 3))
    found = np.zeros(P, bool)
    ok = first[depth[first] >= 0]  # inside a near triangle
    best[pi[ok]], found[pi[ok]] = ti[ok], True
    lam[pi[ok]] = np.stack([l0[ok], l1[ok], l2[ok]], axis=1)
    redo = np.flatnonzero(~found)
    if redo.size:  # outside every near triangle: all of them (the nearest, clamped)
        m0, m1, m2 = _barycentrics(points[redo, None, :], a[None], e1[None], e2[None], det[None])
        jj = np.minimum(np.minimum(m0, m1), m2).argmax(axis=1)
        rr = np.arange(redo.size)
        best[redo], lam[redo] = jj, np.stack([m0[rr, jj], m1[rr, jj], m2[rr, jj]], axis=1)
    w = np.clip(lam, 0, None)
    w /= w.sum(axis=1, keepdims=True)
    tri = triangles[best]
    out = np.einsum("pk,pkc->pc", w, mesh[tri])
    out[:, :2] = points  # keep the tracked position exactly; only z comes from the mesh
    return out


def driver_motion(track: DriverTrack, params: DriverParams = DriverParams(), *, shape_mask=None) -> DriverMotion:
    """Rigid/non-rigid decomposition of a tracked driver in the canonical frame (module doc).

    ``shape_mask`` (H, W) bool in the canonical frame: further limits the grid's valid area."""
    from ..geometry._generic_face import canonical_frame, load_generic_face
    from ..landmarks import POINTS49_INDEX

    found = track.found
    mesh = fill_lost(track.mesh, found)
    p68 = fill_lost(track.points68, found)
    mean, s, R, t = generalized_procrustes(mesh[found], iters=params.procrustes_iters)
    # pose of every frame (interpolated for lost frames; rotation by its rotation vector)
    from scipy.spatial.transform import Rotation

    n = len(found)
    rv = np.zeros((n, 3))
    rv[found] = Rotation.from_matrix(R).as_rotvec()
    ls, tt = np.zeros(n), np.zeros((n, 3))
    ls[found], tt[found] = np.log(s), t
    rv, ls, tt = (fill_lost(a, found) for a in (rv, ls, tt))
    aligned = np.einsum("nij,nvj->nvi", Rotation.from_rotvec(rv).as_matrix().transpose(0, 2, 1),
                        mesh - tt[:, None]) / np.exp(ls)[:, None, None]
    w, o = params.smooth_window, params.smooth_order
    aligned = smooth_series(aligned, w, o)
    rv, ls, tt = smooth_series(rv, w, o), smooth_series(ls, w, o), smooth_series(tt, w, o)
    # mean mesh -> canonical frame: anchors (vertices at the fiducials) onto the mean frontalized
    # fiducials (x, y) and the generic face's depth (z)
    anchors = _anchor_vertices(p68, mesh, found)
    frame = canonical_frame(params.size)
    gen = load_generic_face().points68
    fid_mean = track.frontal_points68.mean(axis=0)
    target = np.c_[fid_mean, gen[:, 2] * frame.scale][POINTS49_INDEX]
    sc, Rc, tc = similarity_procrustes(mean[anchors[POINTS49_INDEX]], target)
    mean_c = sc * mean @ Rc.T + tc
    deltas = sc * (aligned - mean) @ Rc.T
    # image = s R X_mean + t,  X_mean = Rc^T (X_c - tc) / sc
    Rf = Rotation.from_rotvec(rv).as_matrix()
    A = (np.exp(ls) / sc)[:, None, None] * Rf @ Rc.T
    b = tt - np.einsum("nij,j->ni", A, tc)
    # expression fiducials: tracked points lifted on their frame's mesh, un-posed (lost frames interpolated)
    from scipy.spatial import Delaunay

    triangles = Delaunay(mean[:, :2]).simplices
    fid68 = np.zeros((n, 68, 2))
    for i in np.flatnonzero(found):
        x3 = _lift_points(p68[i], mesh[i], triangles)
        fid68[i] = (np.linalg.solve(A[i], (x3 - b[i]).T).T)[:, :2]
    filled = fill_lost(fid68, found)
    fid68 = smooth_series(filled, w, o)
    if params.lip_smooth_window != w:
        mouth_pts = list(_MOUTH_FIDUCIALS)
        fid68[:, mouth_pts] = smooth_series(filled[:, mouth_pts], params.lip_smooth_window, o)
    fid = fid68[:, POINTS49_INDEX]
    # depth-map grid
    W, H = params.size
    st = int(params.grid_step)
    gy, gx = np.mgrid[0:H:st, 0:W:st].astype(np.float64)
    grid = GridInterpolator(mean_c[:, :2], np.stack([gx, gy], axis=-1))
    if shape_mask is not None:
        grid.mask &= np.asarray(shape_mask, bool)[::st, ::st]
    z = grid(mean_c[:, 2])
    gm = np.stack([gx, gy, np.where(grid.mask, z, np.nan)], axis=-1)
    mouth = None
    if params.mouth_correction:
        at = GridInterpolator(mean_c[:, :2], fid68[found].mean(axis=0))  # the mesh's motion at the mean landmarks
        mouth = MouthCorrection(fid68, at(deltas.transpose(1, 0, 2)).transpose(1, 0, 2)[..., :2], found,
                                np.stack([gx, gy], axis=-1))
    return DriverMotion(pose_A=A, pose_b=b, mean_mesh=mean_c, deltas=deltas, fiducials=fid,
                        mean_fiducials=fid[found].mean(axis=0), grid=grid, grid_mesh=gm, grid_step=st,
                        found=found.copy(), opening=mouth_opening(p68), points68=p68, anchors=anchors,
                        mouth=mouth, fiducials68=fid68, triangles=triangles, frontal_mean68=fid_mean)


# eyelid landmarks (iBUG): per eye the corners, the upper lid and the lower lid (paired top-bottom)
_EYES = (((36, 39), (37, 38), (41, 40)), ((42, 45), (43, 44), (47, 46)))
_UPPER_LIDS = (37, 38, 43, 44)
_LOWER_LIDS = (41, 40, 47, 46)
#: what the lid splines hold still: eye corners, brows, nose, jaw line and mouth
_LID_STILL = (36, 39, 42, 45) + tuple(range(0, 36)) + tuple(range(48, 68))


def eye_openness(points68) -> np.ndarray:
    """Eye aspect ratio (both eyes' mean of (|p1 - p5| + |p2 - p4|) / 2 |p0 - p3|, Soukupova and
    Cech 2016) per face: (...,) for (..., 68, 2)."""
    p = np.asarray(points68, np.float64)
    out = 0.0
    for (c0, c1), (u0, u1), (l0, l1) in _EYES:
        h = np.linalg.norm(p[..., u0, :] - p[..., l0, :], axis=-1) + np.linalg.norm(p[..., u1, :] - p[..., l1, :],
                                                                                    axis=-1)
        w = np.linalg.norm(p[..., c0, :] - p[..., c1, :], axis=-1)
        out = out + h / np.maximum(2.0 * w, 1e-9)
    return out / 2.0


class LidFields:
    """Thin-plate-spline fields of eyelid motion on a grid, split at each eye's opening (the
    eyes' counterpart of :class:`LipFields`).

    ``mean68`` (68, 2) the face's mean landmarks, ``grid_xy`` (h, w, 2) grid positions (same
    frame). :meth:`__call__` takes motions (68, 2) of the landmarks (only the upper and lower
    lid points 37, 38, 43, 44 / 41, 40, 47, 46 are read; eye corners, brows, nose, jaw and mouth
    are held still) and returns the (h, w, 2) field: the upper lids' spline above the upper lid
    contour, the lower lids' below the lower contour, and across each eye's opening a linear
    blend, so a lid closes over the eye (a blink) instead of the whole eye region sliding.
    """

    def __init__(self, mean68: np.ndarray, grid_xy: np.ndarray, smoothing: float = 1.0):
        from scipy.interpolate import RBFInterpolator

        p = np.asarray(mean68, np.float64)
        self.shape = grid_xy.shape[:2]
        g = np.asarray(grid_xy, np.float64).reshape(-1, 2)
        ops = []
        for moving in (_UPPER_LIDS, _LOWER_LIDS):
            idx = list(moving) + list(_LID_STILL)
            rbf = RBFInterpolator(p[idx], np.eye(len(idx)), kernel="thin_plate_spline", smoothing=smoothing)
            ops.append((np.asarray(moving), rbf(g)[:, : len(moving)].astype(np.float32)))
        self.upper, self.lower = ops
        # weight of the lower field: 0 above an eye's upper lid, 1 below its lower lid, linear across
        # the opening; away from the eyes a sigmoid about the eyes' mid line (the fields vanish there)
        x, y = g[:, 0], g[:, 1]
        side = None
        dist = np.full(len(g), np.inf)
        for (c0, c1), (u0, u1), (l0, l1) in _EYES:
            ux, uy = p[[c0, u0, u1, c1], 0], p[[c0, u0, u1, c1], 1]
            lx, ly = p[[c0, l0, l1, c1], 0], p[[c0, l0, l1, c1], 1]
            y_up = np.interp(x, *_increasing(ux, uy))
            y_lo = np.interp(x, *_increasing(lx, ly))
            band = np.maximum(y_lo - y_up, 0.5)
            inside = np.clip((y - y_up) / band, 0.0, 1.0)
            outside = np.maximum(0.0, np.maximum(min(ux) - x, x - max(ux)))
            sig = 1.0 / (1.0 + np.exp(-np.clip((y - (y_up + y_lo) / 2) / (0.3 + 0.5 * outside), -50, 50)))
            this = np.where(outside > 0, sig, inside)
            near = outside < dist  # each grid point follows its nearer eye
            side = this if side is None else np.where(near, this, side)
            dist = np.minimum(dist, outside)
        self.side = side.astype(np.float32)

    def __call__(self, motion68) -> np.ndarray:
        return _upper_lower_field(self, motion68)
