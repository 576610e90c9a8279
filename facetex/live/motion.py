"""The driver's motion, frame by frame as frames arrive (the causal counterpart of
:func:`facetex.puppet.motion.driver_motion`).

* **Tracking** (:class:`CausalTracker`): dlib's 68 landmarks fitted in the detector box carried
  along by the previous frame's landmarks, and MediaPipe's 468-point face mesh seeded by them
  (:func:`facetex.puppet.driver._track_frame`); the HOG face detector runs only when the face was
  lost (the offline tracker also re-detects every 10 frames; here the box is re-derived from the
  detection's anchor every frame, so it does not drift). A face partly outside the frame or whose
  landmarks and mesh disagree is lost (:func:`facetex.puppet.driver.face_rejection`).
* **Reference** (:func:`reference_motion`): what the offline puppetry takes from the whole clip —
  the mean mesh (its canonical frame), the mean landmarks (the expression's zero, the lips' and
  eyes' rest) — is made once from the first tracked frames (:class:`~facetex.live.LiveParams`
  ``warmup``), with the offline code on those frames.
* **Per frame** (:class:`LiveMotion`): the head pose is the similarity from the reference mean mesh
  to the frame's mesh (the offline pose is fitted to the clip's Procrustes mean: the same up to one
  similarity), the expression is the mesh's residual after removing that pose, and the landmarks are
  lifted onto the frame's mesh and un-posed, exactly as offline; each is then smoothed by a causal
  One-Euro filter (:mod:`facetex.live.filters`) instead of the offline Savitzky-Golay filter, which
  looks two frames ahead. The lip and jaw landmarks are not smoothed (as offline)."""

from __future__ import annotations

import math

import numpy as np

from ..puppet.driver import (
    _MOUTH_FIDUCIALS,
    DriverParams,
    DriverTrack,
    _track_frame,
    face_rejection,
    similarity_procrustes,
)
from ..puppet.motion import DriverMotion, _lift_points, driver_motion
from .filters import OneEuroFilter
from .params import LiveParams

__all__ = ["CausalTracker", "load_tracking_models", "reference_motion", "shape_residual", "LiveMotion"]


def load_tracking_models() -> None:
    """Load dlib's face detector and landmark model and the face mesh network now (~1.5 s), not at
    the first frame."""
    from ..landmarks import _model

    for name in ("hog", "shape68", "mesh"):
        _model(name)


class CausalTracker:
    """Face tracking of one stream, frame by frame (module doc).

    Parameters
    ----------
    params : DriverParams
        ``min_mesh_score``: the face mesh's presence score below which the face is lost.
    """

    def __init__(self, params: DriverParams = DriverParams()):
        self.params = params
        self.prev = None  # (points68, anchor) of the previous frame with a face
        self.detections = 0

    def __call__(self, frame: np.ndarray) -> tuple:
        """(points68 (68, 2), mesh (468, 3), score, "") of the face in a uint8 RGB frame, or
        (None, None, score, why) when it is lost (why: a :data:`facetex.puppet.driver.LOST_REASONS` key)."""
        detect = self.prev is None
        self.detections += detect
        r = _track_frame(frame, self.prev, self.params, detect)
        why = "no face" if r is None else face_rejection(r[0], r[1], (frame.shape[1], frame.shape[0]))
        if why:
            self.prev = None
            return None, None, 0.0 if r is None else r[2], why
        p68, mesh, score, anchor = r
        self.prev = (p68, anchor)
        return p68, mesh, score, ""

    def lose(self) -> None:
        """Forget the face (the next frame runs the detector)."""
        self.prev = None


def reference_motion(points68, meshes, scores, frame_size, *, fps: float = 25.0,
                     params: DriverParams = DriverParams(), rims=None) -> tuple[DriverTrack, DriverMotion]:
    """(DriverTrack, DriverMotion) of K tracked frames (``points68`` (K, 68, 2), ``meshes`` (K, 468, 3)
    in the pixels of frames of ``frame_size`` (W, H)), made by the offline code: the reference of a
    live stream (its mean mesh, canonical frame, mean landmarks; ``rims`` the frames'
    :func:`~facetex.geometry.glasses.rim_template`, the driver's glasses)."""
    from ..geometry.frontalize import pose_corrected_points68

    p = np.asarray(points68, np.float64).reshape(-1, 68, 2)
    m = np.asarray(meshes, np.float64).reshape(-1, 468, 3)
    k = len(p)
    W, H = frame_size
    frontal = np.array([pose_corrected_points68((H, W, 3), q, size=params.size) for q in p])
    cw, ch = params.size
    track = DriverTrack(points68=p, mesh=m, found=np.ones(k, bool), score=np.asarray(scores, np.float64),
                        frontal=np.zeros((0, ch, cw, 3), np.float32), frontal_points68=frontal,
                        frame_size=(int(W), int(H)), fps=float(fps), path="<live>", has_audio=False,
                        lost_reason=[""] * k, rims=rims)
    return track, driver_motion(track, params)


def shape_residual(points68, mean68) -> float:
    """Mean distance of ``points68`` (similarity-aligned) from ``mean68``, over the latter's outer
    eye-corner distance (the measure of :func:`facetex.puppet.driver.implausible_shapes`)."""
    iod = float(np.linalg.norm(mean68[36] - mean68[45]))
    s, R, t = similarity_procrustes(points68, mean68)
    return float(np.linalg.norm(s * points68 @ R.T + t - mean68, axis=1).mean() / max(iod, 1e-9))


def _rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector (axis x angle) of a 3x3 rotation (angle < pi)."""
    c = (np.trace(R) - 1.0) / 2.0
    angle = math.acos(min(1.0, max(-1.0, c)))
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-8:
        return w / 2.0
    return w * (angle / (2.0 * math.sin(angle)))


def _rotation(rv: np.ndarray) -> np.ndarray:
    """3x3 rotation of a rotation vector (Rodrigues)."""
    angle = float(np.linalg.norm(rv))
    if angle < 1e-12:
        return np.eye(3)
    k = rv / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * (K @ K)


class LiveMotion:
    """Per-frame pose, expression residuals and un-posed landmarks against a reference (module doc).

    Parameters
    ----------
    reference : DriverMotion
        :func:`reference_motion` of the first frames.
    live : LiveParams
        The One-Euro filters' settings.
    """

    def __init__(self, reference: DriverMotion, live: LiveParams = LiveParams()):
        self.mean = reference.mean_mesh
        self.triangles = reference.triangles
        self.live = live
        self.mouth = np.zeros(68, bool)
        self.mouth[list(_MOUTH_FIDUCIALS)] = True
        self.pose_f = OneEuroFilter(live.pose)
        self.shape_f = OneEuroFilter(live.shape)
        self.fid_f = OneEuroFilter(live.landmarks)
        self.lip_f = OneEuroFilter(live.lips) if live.lips is not None else None
        self.t_prev: float | None = None

    def reset(self) -> None:
        """Forget the past (after a lost face: the next frame is not smoothed towards the old one)."""
        for f in (self.pose_f, self.shape_f, self.fid_f, self.lip_f):
            if f is not None:
                f.reset()
        self.t_prev = None

    def __call__(self, points68: np.ndarray, mesh: np.ndarray, t: float) -> dict:
        """{"A" (3, 3), "b" (3,), "deltas" (468, 3), "fiducials68" (68, 2)} of a frame at time ``t``
        (seconds): image pixel = A X + b of a canonical point X (as :class:`DriverMotion`'s pose)."""
        dt = 1.0 / 25 if self.t_prev is None else max(t - self.t_prev, 1e-3)
        self.t_prev = t
        s, R, tr = similarity_procrustes(self.mean, mesh)  # mesh ~ s R mean + tr
        aligned = (mesh - tr) @ R / s  # R^T (mesh - tr) / s, the pose removed
        pose = self.pose_f(np.r_[_rotvec(R), math.log(s), tr], dt)
        A = math.exp(pose[3]) * _rotation(pose[:3])
        b = pose[4:]
        deltas = self.shape_f(aligned - self.mean, dt)
        x3 = _lift_points(np.asarray(points68, np.float64), mesh, self.triangles)
        fid = np.linalg.solve(A, (x3 - b).T).T[:, :2]
        out = np.empty_like(fid)
        out[~self.mouth] = self.fid_f(fid[~self.mouth], dt)
        out[self.mouth] = fid[self.mouth] if self.lip_f is None else self.lip_f(fid[self.mouth], dt)
        return {"A": A, "b": b, "deltas": deltas, "fiducials68": out}
