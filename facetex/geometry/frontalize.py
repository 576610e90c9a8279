"""Face frontalization with a generic 3D face (Tom Hanks Sec. 5, after Hassner et al. 2015,
"Effective face frontalization in unconstrained images").

1. Pose: ``cv2.solvePnP`` between the detected 2D landmarks and the generic
   model's 3D landmarks (:func:`estimate_head_pose`).
2. Back-projection: every pixel of the canonical frontal frame is a 3D point on
   the generic surface (``_generic_face``); it is projected into the photo with
   the estimated pose and the photo is sampled there (``cv2.remap``).
3. Visibility: canonical pixels hidden behind other parts of the surface in the
   photo (z-buffer) get 0; visible ones are weighted by how densely the photo
   samples them relative to a frontal view (cosines of the surface normal with
   the two view directions).
4. Soft symmetry: poorly visible pixels are filled from the mirrored side of the
   face, weighted by visibility (Hassner et al. Sec. 3.3), feathered and brightness-matched
   (:func:`symmetry_fill_image`). Collections should weight the fill down
   (:func:`fill_confidence`).

The canonical frame (an orthographic frontal view with the eye centres at fixed
positions) and the generic model are described in ``_generic_face``.
Pose angles (degrees): yaw > 0 when the nose points to the image's right (the
subject turns to their left), pitch > 0 when it points down, roll > 0 when the
face is turned clockwise in the image; R = Rz(roll) Ry(-yaw) Rx(pitch) in
OpenCV camera axes (x right, y down, z forward).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import BadInputError
from ._generic_face import (
    CANONICAL_SIZE,
    CanonicalFrame,
    canonical_frame,
    canonical_surface,
    load_generic_face,
    surface_on_frame,
)
from .masks import disc

__all__ = [
    "HeadPose",
    "Frontalized",
    "estimate_head_pose",
    "frontalize",
    "canonical_points68",
    "rotation_from_angles",
    "rotate_face",
    "fill_confidence",
    "symmetry_fill_image",
    "PNP_INDEX",
    "CANONICAL_SIZE",
]

#: Landmarks used for the pose: the paper's 49 fiducials (iBUG 68 without the 17 jaw
#: points and the inner-mouth corners 60, 64). Jaw points are silhouette points that
#: slide over the surface as the head turns, so they are not fixed 3D points.
PNP_INDEX = np.array([i for i in range(17, 68) if i not in (60, 64)], dtype=np.intp)
#: Jaw (contour) points: pose-corrected by the ray's closest point to the model point.
_JAW = np.arange(17)
#: Depth slack (mm) of the z-buffer test: occluders (nose, cheek) are much further in front.
ZBUFFER_TOLERANCE_MM = 5.0
#: A ray's surface hit further than this (mm) from the model landmark is not trusted.
MAX_HIT_DISTANCE_MM = 15.0
#: Smoothing (canonical px at the default size) of the z-buffer mask, against blocky seams.
VISIBILITY_BLUR_PX = 1.5
#: Erosion and feather (px at a 192 px wide frame) of the own side's weight in the symmetry fill.
FILL_FEATHER_PX = 3.0
#: Scale (px at a 192 px wide frame) of the local brightness match of the mirrored side.
FILL_GAIN_PX = 12.0
#: Scale (px at a 192 px wide frame) of the normalised convolution that fills the face's pixels
#: neither side saw, and the share of determined pixels around one at which it fills it wholly.
HOLE_FILL_PX = 4.0
HOLE_SUPPORT = 0.3
#: Off-photo samples blend from the replicated border into a smooth continuation over this many
#: (sampled-photo) pixels.
OUTSIDE_RAMP_PX = 3.0
#: Head rotation centre of :func:`rotate_face` in model coordinates (mm): behind the eyes.
HEAD_CENTRE_MM = (0.0, 20.0, 90.0)


def rotation_from_angles(yaw: float = 0.0, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """3x3 rotation R = Rz(roll) Ry(-yaw) Rx(pitch) of angles in degrees (module docstring)."""
    a, b, g = math.radians(pitch), math.radians(-yaw), math.radians(roll)
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    rz = np.array([[math.cos(g), -math.sin(g), 0], [math.sin(g), math.cos(g), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _angles(r: np.ndarray) -> tuple[float, float, float]:
    b = math.asin(float(np.clip(-r[2, 0], -1.0, 1.0)))
    a = math.atan2(r[2, 1], r[2, 2])
    g = math.atan2(r[1, 0], r[0, 0])
    return -math.degrees(b), math.degrees(a), math.degrees(g)


@dataclass(frozen=True, eq=False)
class HeadPose:
    """Rigid pose of the generic model in a photo: x_cam = R X + t, pixel = K x_cam (no distortion).

    rvec, tvec: OpenCV Rodrigues vector and translation (mm); K: 3x3 camera matrix;
    yaw, pitch, roll: degrees (module docstring); rms_px: RMS reprojection error of the
    landmarks used.
    """

    rvec: np.ndarray
    tvec: np.ndarray
    K: np.ndarray
    yaw: float
    pitch: float
    roll: float
    rms_px: float

    @property
    def R(self) -> np.ndarray:
        return cv2.Rodrigues(self.rvec)[0]

    def to_camera(self, xyz: np.ndarray) -> np.ndarray:
        return np.asarray(xyz, dtype=np.float64) @ self.R.T + self.tvec

    def project(self, xyz: np.ndarray) -> np.ndarray:
        """(..., 2) image pixels of (..., 3) model points."""
        c = self.to_camera(xyz)
        p = c @ self.K.T
        return p[..., :2] / p[..., 2:3]

    @property
    def pixels_per_mm(self) -> float:
        """Image scale at the model origin (focal / distance)."""
        return float(self.K[0, 0] / self.tvec[2])


@dataclass(frozen=True, eq=False)
class Frontalized:
    """Result of :func:`frontalize`, all in the canonical frame (H, W) = size[::-1].

    image: (H, W, 3) float32 frontal view (symmetry-filled if asked).
    visibility: (H, W) float32 in [0, 1]: 0 where the generic surface is hidden in the
        photo (self-occlusion) or outside it, < 1 where the photo samples the surface
        more sparsely than a frontal view (foreshortening); before any symmetry fill.
    points68: (68, 2) pose-corrected landmarks (see :func:`frontalize`).
    pose: the :class:`HeadPose`.
    map: (H, W, 2) float32 photo (x, y) sampled by every canonical pixel (``cv2.remap``).
    face_mask: (H, W) bool, canonical pixels on the generic mesh (the rest is its extension).
    """

    image: np.ndarray
    visibility: np.ndarray
    points68: np.ndarray
    pose: HeadPose
    map: np.ndarray
    face_mask: np.ndarray

    def warp(self, image: np.ndarray, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
        """Frontalize another image or mask of the same photo with the same sampling map."""
        a = np.asarray(image)
        if a.dtype == np.float64 or a.dtype == bool:
            a = a.astype(np.float32)
        return cv2.remap(a, self.map[..., 0], self.map[..., 1], interpolation, borderMode=cv2.BORDER_REPLICATE)


def _check_points(points68) -> np.ndarray:
    p = np.asarray(points68, dtype=np.float64) if not isinstance(points68, (str, bytes)) else np.empty(0)
    if p.shape != (68, 2):
        raise BadInputError(f"expected 68 landmark points of shape (68, 2), got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise BadInputError("landmark points contain NaN or infinite values: detect the landmarks again")
    return p


def _check_image(image) -> np.ndarray:
    a = np.asarray(image)
    if a.ndim != 3 or a.shape[2] != 3 or min(a.shape[:2]) < 8:
        raise BadInputError(f"expected an (H, W, 3) RGB image, got an array of shape {a.shape}")
    if a.dtype == np.uint8:
        return a.astype(np.float32) / 255.0
    if not np.issubdtype(a.dtype, np.floating):
        raise BadInputError(f"expected a float32 image in [0, 1] (or uint8), got dtype {a.dtype}")
    return np.ascontiguousarray(a, dtype=np.float32)


def _image_hw(image_shape) -> tuple[int, int]:
    try:
        h, w = int(image_shape[0]), int(image_shape[1])
    except (TypeError, ValueError, IndexError):
        raise BadInputError(f"image_shape must be (H, W[, C]), got {image_shape!r}") from None
    if h < 1 or w < 1:
        raise BadInputError(f"image_shape must be positive, got {image_shape!r}")
    return h, w


def estimate_head_pose(points68, image_shape, *, focal: float | None = None) -> HeadPose:
    """Pose of the generic face from 68 (x, y) landmarks of an image of ``image_shape``.

    Perspective camera with square pixels, principal point at the image centre and
    ``focal`` in pixels (default max(H, W), a ~53 degree field of view: the focal of a
    photo is unknown, and at face distances the result depends on it only weakly).
    Solved by ``cv2.solvePnP`` (SQPnP, then Levenberg-Marquardt refinement) on the
    :data:`PNP_INDEX` points.
    """
    p = _check_points(points68)
    h, w = _image_hw(image_shape)
    f = float(max(h, w) if focal is None else focal)
    if not (f > 0 and math.isfinite(f)):
        raise BadInputError(f"focal must be a positive number of pixels, got {focal!r}")
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    obj = load_generic_face().points68[PNP_INDEX]
    img = p[PNP_INDEX]
    if np.linalg.matrix_rank(img - img.mean(axis=0), tol=1e-6) < 2:
        raise BadInputError("landmark points are degenerate (all on a line or one point): detect them again")
    ok, rvec, tvec = cv2.solvePnP(obj, img, K, None, flags=cv2.SOLVEPNP_SQPNP)
    if ok:
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, None, rvec, tvec)
    if not ok or not np.all(np.isfinite(tvec)) or tvec[2, 0] <= 0:
        raise BadInputError("no head pose fits these landmarks: check that they are 68 iBUG points of one face")
    rvec, tvec = rvec.ravel(), tvec.ravel()
    proj = cv2.projectPoints(obj, rvec, tvec, K, None)[0].reshape(-1, 2)
    rms = float(np.sqrt(((proj - img) ** 2).sum(axis=1).mean()))
    yaw, pitch, roll = _angles(cv2.Rodrigues(rvec)[0])
    return HeadPose(rvec, tvec, K, yaw, pitch, roll, rms)


def canonical_points68(size=CANONICAL_SIZE) -> np.ndarray:
    """The generic face's 68 landmarks in the canonical frame of ``size`` (W, H), (68, 2)."""
    return canonical_frame(size).project(load_generic_face().points68)


def _ray_mesh(dirs, verts, tris, boxes, pts, targets) -> np.ndarray:
    """Distance along unit rays ``dirs`` (N, 3) from the camera centre to their intersection
    with a triangle mesh (camera coordinates) that lies nearest to ``targets`` (N, 3); inf on
    a miss. Candidate triangles are those whose image bounding box ``boxes`` (T, 4) holds the
    ray's pixel ``pts`` (N, 2); then Moller-Trumbore (hand-written: no ray caster among the
    dependencies). Nearest to the target rather than front-most, so a landmark hidden behind
    the nose keeps its own surface."""
    cand = (
        (pts[:, None, 0] >= boxes[None, :, 0]) & (pts[:, None, 0] <= boxes[None, :, 2])
        & (pts[:, None, 1] >= boxes[None, :, 1]) & (pts[:, None, 1] <= boxes[None, :, 3])
    )
    ri, ti = np.nonzero(cand)
    out = np.full(len(dirs), np.inf)
    if len(ri) == 0:
        return out
    tri = tris[ti]
    a, b, c = verts[tri[:, 0]], verts[tri[:, 1]], verts[tri[:, 2]]
    e1, e2 = b - a, c - a
    d = dirs[ri]
    pv = np.cross(d, e2)
    det = np.einsum("ij,ij->i", pv, e1)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tv = -a  # camera centre at the origin
    u = np.einsum("ij,ij->i", tv, pv) * inv
    qv = np.cross(tv, e1)
    v = np.einsum("ij,ij->i", d, qv) * inv
    t = np.einsum("ij,ij->i", e2, qv) * inv
    hit = ok & (u >= -1e-9) & (v >= -1e-9) & (u + v <= 1 + 1e-9) & (t > 0)
    ri, t, d = ri[hit], t[hit], d[hit]
    miss = np.linalg.norm(d * t[:, None] - targets[ri], axis=1)
    best = np.full(len(dirs), np.inf)
    np.minimum.at(best, ri, miss)
    win = miss <= best[ri]
    out[ri[win]] = t[win]
    return out


def _pose_corrected_points(points68: np.ndarray, pose: HeadPose, frame: CanonicalFrame) -> np.ndarray:
    """Back-project the detected points through the pose onto the generic surface and project them
    frontally. Inner points: the ray's hit on the mesh nearest to the posed model point (if within
    MAX_HIT_DISTANCE_MM of it); jaw points and misses: the point of the ray closest to the posed
    model point (contour points slide over the surface, a surface hit would be wrong)."""
    g = load_generic_face()
    kinv = np.linalg.inv(pose.K)
    rays = np.c_[points68, np.ones(68)] @ kinv.T
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    model = pose.to_camera(g.points68)
    closest = rays * (rays * model).sum(axis=1, keepdims=True)
    inner = np.setdiff1d(np.arange(68), _JAW)
    verts = pose.to_camera(g.vertices)
    vp = verts[:, :2] / verts[:, 2:3] * pose.K[0, 0] + pose.K[:2, 2]
    tp = vp[g.triangles]
    boxes = np.concatenate([tp.min(axis=1) - 0.5, tp.max(axis=1) + 0.5], axis=1)
    t = _ray_mesh(rays[inner], verts, g.triangles, boxes, points68[inner], model[inner])
    hits = rays[inner] * np.where(np.isfinite(t), t, 0.0)[:, None]
    good = np.isfinite(t) & (np.linalg.norm(hits - model[inner], axis=1) < MAX_HIT_DISTANCE_MM)
    cam = closest.copy()
    cam[inner[good]] = hits[good]
    xyz = (cam - pose.tvec) @ pose.R  # back to model coordinates
    return frame.project(xyz)


def _zbuffer_visible(z: np.ndarray, proj: np.ndarray, bin_px: float, tol: np.ndarray) -> np.ndarray:
    """True where a point (depth ``z`` (N,), pixel ``proj`` (N, 2)) is the front-most, within
    ``tol`` (N,), of the points in its image bin of ``bin_px`` pixels. Hand-written splatting
    z-buffer (np.minimum.at)."""
    if len(z) == 0:
        return np.zeros(0, dtype=bool)
    q = (proj * (1.0 / bin_px)).astype(np.int64)  # proj >= -0.5: truncation is floor up to one bin
    nx = int(q[:, 0].max()) + 2
    key = q[:, 1] * nx + q[:, 0]
    zbuf = np.full(int(key.max()) + 1, np.inf, dtype=z.dtype)
    np.minimum.at(zbuf, key, z)
    return z <= zbuf[key] + tol


def _sample(img: np.ndarray, mp: np.ndarray, pixels_per_canonical: float) -> np.ndarray:
    """cv2.remap, first shrinking (INTER_AREA) the photo's face region when it is much larger
    than the canonical frame, so the sampling does not alias."""
    h, w = img.shape[:2]
    x0 = int(max(0, math.floor(mp[..., 0].min()) - 2))
    y0 = int(max(0, math.floor(mp[..., 1].min()) - 2))
    x1 = int(min(w, math.ceil(mp[..., 0].max()) + 3))
    y1 = int(min(h, math.ceil(mp[..., 1].max()) + 3))
    if x1 - x0 < 2 or y1 - y0 < 2:
        return np.zeros(mp.shape[:2] + (3,), np.float32)
    crop = img[y0:y1, x0:x1]
    m = mp - np.array([x0, y0], dtype=np.float32)
    k = 1.0 / pixels_per_canonical
    if k < 0.67:
        size = (max(2, round((x1 - x0) * k)), max(2, round((y1 - y0) * k)))
        kx, ky = size[0] / (x1 - x0), size[1] / (y1 - y0)
        crop = cv2.resize(crop, size, interpolation=cv2.INTER_AREA)
        m = (m + 0.5) * np.array([kx, ky], dtype=np.float32) - 0.5
    out = cv2.remap(crop, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    # Off the photo, replicating its border rows and columns paints straight streaks (hair and
    # background at the frame's edges, the collar below the chin): there the photo's border is
    # continued smoothly instead, from a heavily blurred copy, blending in over OUTSIDE_RAMP_PX.
    ch, cw = crop.shape[:2]
    dx = np.maximum(np.maximum(-0.5 - m[..., 0], m[..., 0] - (cw - 0.5)), 0)
    dy = np.maximum(np.maximum(-0.5 - m[..., 1], m[..., 1] - (ch - 0.5)), 0)
    a = np.clip(np.maximum(dx, dy) / OUTSIDE_RAMP_PX, 0, 1)[..., None]
    if a.max() > 0:
        s = max(2.0, 0.08 * max(ch, cw))
        soft = cv2.GaussianBlur(crop, (0, 0), s, borderType=cv2.BORDER_REPLICATE)
        far = cv2.remap(soft, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        out = (1 - a) * out + a * far
    return out.astype(np.float32)


def pose_corrected_points68(image_shape, points68, *, size=CANONICAL_SIZE, focal: float | None = None,
                             pose: HeadPose | None = None) -> np.ndarray:
    """(68, 2) pose-corrected landmarks in the canonical frame of ``size``: the ``points68`` of
    :func:`frontalize` without sampling the image (cheap: for trackers that need only these)."""
    p = _check_points(points68)
    if pose is None:
        pose = estimate_head_pose(p, image_shape, focal=focal)
    return _pose_corrected_points(p, pose, canonical_frame(size))


def frontalize(
    image: np.ndarray,
    points68,
    *,
    size=CANONICAL_SIZE,
    symmetry_fill: bool = True,
    focal: float | None = None,
    pose: HeadPose | None = None,
) -> Frontalized:
    """Frontal view of the face in ``image`` (float32 RGB (H, W, 3)) given its 68 landmarks.

    ``size`` (W, H) of the canonical frame (default 192 x 240, the paper's ~194 x 244 face).
    ``pose`` skips :func:`estimate_head_pose` (``focal`` is passed to it otherwise).
    Pose-corrected fiducials (``points68`` of the result): each detected point is
    back-projected through the estimated pose onto the generic surface and projected
    frontally, so they keep the photo's non-rigid residual (expression, identity) and
    lose its rigid pose; a perfectly generic face gives :func:`canonical_points68`.
    With ``symmetry_fill`` the poorly visible side is filled from the mirrored one
    (:func:`symmetry_fill_image`: soft symmetry, Hassner et al. Sec. 3.3, feathered and
    brightness-matched so it leaves no seam).
    """
    img = _check_image(image)
    p = _check_points(points68)
    if pose is None:
        pose = estimate_head_pose(p, img.shape, focal=focal)
    surf = canonical_surface(size)
    frame = surf.frame
    W, H = frame.size
    R = pose.R
    Rt = np.c_[R, pose.tvec]
    cam = cv2.transform(surf.xyz_flat[:, None, :], Rt)[:, 0]  # (N, 3) float32 camera coordinates
    z = cam[:, 2]
    front = z > 1.0
    zinv = 1.0 / np.where(front, z, 1.0)
    K = pose.K
    mpf = np.empty((len(cam), 2), dtype=np.float32)
    mpf[:, 0] = cam[:, 0] * zinv * K[0, 0] + K[0, 2]
    mpf[:, 1] = cam[:, 1] * zinv * K[1, 1] + K[1, 2]
    mpf[~front] = -1e4
    mp = mpf.reshape(H, W, 2)
    ratio = pose.pixels_per_mm / frame.scale  # photo pixels per canonical pixel
    sampled = _sample(img, mp, ratio)

    # visibility: z-buffer x foreshortening relative to the frontal view
    h, w = img.shape[:2]
    inside = front & (mpf[:, 0] > -0.5) & (mpf[:, 0] < w - 0.5) & (mpf[:, 1] > -0.5) & (mpf[:, 1] < h - 0.5)
    seen = np.zeros(len(cam), dtype=bool)
    bin_px = 1.5 * max(ratio, 1e-6)
    # slack: a fixed margin plus the depth a steep surface spans within one bin (its own wall)
    tol = ZBUFFER_TOLERANCE_MM + surf.slope_flat[inside] * np.float32(2.0 * bin_px / pose.pixels_per_mm)
    seen[inside] = _zbuffer_visible(z[inside], mpf[inside] + 0.5, bin_px, tol)
    # cos between the posed normal and the direction to the camera
    nc = cv2.transform(surf.normals_flat[:, None, :], R)[:, 0]
    cos_cam = -np.einsum("ij,ij->i", nc, cam) / np.sqrt(np.einsum("ij,ij->i", cam, cam))
    density = np.clip(cos_cam / surf.cos_frontal_flat, 0.0, 1.0).reshape(H, W)
    seen = seen.reshape(H, W).astype(np.float32)
    vis = (cv2.GaussianBlur(seen, (0, 0), VISIBILITY_BLUR_PX * W / CANONICAL_SIZE[0]) * seen * density).astype(
        np.float32
    )

    out = symmetry_fill_image(sampled, vis, surf.on_mesh) if symmetry_fill else sampled
    pts = _pose_corrected_points(p, pose, frame)
    mp.setflags(write=False)
    return Frontalized(np.clip(out, 0.0, 1.0, dtype=np.float32), vis, pts, pose, mp, np.array(surf.on_mesh))


def symmetry_fill_image(image: np.ndarray, visibility: np.ndarray, region: np.ndarray | None = None) -> np.ndarray:
    """Soft symmetry fill (Hassner et al. Sec. 3.3), without the seam.

    I' = (v I + (1 - v) v_m g I_m) / (v + (1 - v) v_m) with I_m, v_m the left-right mirrors of
    the image and the visibility, and two changes against a hard seam where the own side meets
    the mirrored one: v is the visibility eroded and feathered (:data:`FILL_FEATHER_PX`), so the
    own side fades out before its occluded edge (where the sampling smears), and the mirrored
    side is gain-matched by g = local mean of I / local mean of I_m over the pixels both sides
    saw (normalised convolution, :data:`FILL_GAIN_PX`; the two cheeks are lit differently), so
    the fill has the own side's brightness and colour. Pixels of ``region`` (bool (H, W), the
    generic face, grown by :data:`HOLE_FILL_PX`) that neither side saw (v + (1 - v) v_m < 1e-3: a
    narrow band at the cheek's edge of a turned face, where the mirrored cheek's edge is hidden
    too) would keep the photo's raw sample there, its silhouette's background and ear: they take
    the normalised convolution of the determined pixels around them (:data:`HOLE_FILL_PX`), wholly
    where those are at least :data:`HOLE_SUPPORT` of the neighbourhood (a wide area nobody saw
    keeps its samples)."""
    img = np.asarray(image, np.float32)
    vis = np.asarray(visibility, np.float32)
    H, W = vis.shape
    k = W / CANONICAL_SIZE[0]
    r = max(1, int(round(FILL_FEATHER_PX * k)))
    core = cv2.erode((vis > 0.5).astype(np.uint8), disc(r))
    v = np.minimum(vis, cv2.GaussianBlur(core.astype(np.float32), (0, 0), FILL_FEATHER_PX * k))
    vm = v[:, ::-1]
    mir = img[:, ::-1]
    both = ((vis > 0.9) & (vis[:, ::-1] > 0.9)).astype(np.float32)
    gain = np.ones_like(img)
    if both.sum() > 16:
        glob = (img * both[..., None]).sum((0, 1)) / np.maximum((mir * both[..., None]).sum((0, 1)), 1e-6)
        gain = np.broadcast_to(glob, img.shape).astype(np.float32)
        for sg in (4 * FILL_GAIN_PX * k, 2 * FILL_GAIN_PX * k, FILL_GAIN_PX * k):  # coarse to fine
            n = cv2.GaussianBlur(both, (0, 0), sg)[..., None]
            num = cv2.GaussianBlur(img * both[..., None], (0, 0), sg)
            den = cv2.GaussianBlur(mir * both[..., None], (0, 0), sg)
            t = np.clip(n / 0.2, 0, 1)  # where this scale has support, its ratio; else the coarser one
            gain = t * (num / np.maximum(den, 1e-6)) + (1 - t) * gain
        gain = np.clip(gain, 0.5, 2.0).astype(np.float32)
    wm = (1.0 - v) * vm
    den = v + wm
    low = den < 1e-3
    inv = 1.0 / np.maximum(den, np.float32(1e-3))
    a = np.where(low, np.float32(1.0), v * inv)[..., None]
    b = np.where(low, np.float32(0.0), wm * inv)[..., None]
    out = (a * img + b * gain * mir).astype(np.float32)
    if region is None:
        region = np.ones((H, W), bool)
    else:  # the mesh's own edge too: its last columns at a turned cheek are samples of the silhouette
        region = cv2.dilate(np.asarray(region, np.uint8), disc(max(1, int(round(HOLE_FILL_PX * k))))) > 0
    holes = low & region
    if holes.any():  # Normalised convolution of the determined pixels, by hand (cv2 has no masked blur)
        wt = (~low).astype(np.float32)  # every determined pixel alike: each is a normalised fill
        n = cv2.GaussianBlur(wt, (0, 0), HOLE_FILL_PX * k)
        nc = cv2.GaussianBlur(out * wt[..., None], (0, 0), HOLE_FILL_PX * k) / np.maximum(n, 1e-6)[..., None]
        t = (holes * np.clip(n / HOLE_SUPPORT, 0.0, 1.0)).astype(np.float32)[..., None]
        out = (1.0 - t) * out + t * nc
    return out.astype(np.float32)


def fill_confidence(visibility, points68=None, *, mirror_weight: float = 0.1, feather: float = 2.0,
                    outside_face: float = 0.25, floor: float = 0.02) -> np.ndarray:
    """How much a frontalized image can be trusted per canonical pixel, float32 (..., H, W).

    ``visibility`` (..., H, W) in [0, 1] (or uint8 x 255): the photo's own visibility (before the
    symmetry fill). Pixels the photo saw count fully; pixels filled from the mirrored side
    count ``mirror_weight`` (they are the other cheek under other light: a collection blend
    should take them from photos that saw them, which is what removes the fill's oval seam);
    the visibility is Gaussian-feathered (``feather`` px at a 192 px wide frame) so the trust
    has no hard edge. With ``points68`` ((..., 68, 2) pose-corrected landmarks of each photo),
    pixels outside the photo's own face (jaw line and forehead arc, soft edge) count
    ``outside_face``: hair, neck, collar and background do not leak into another photo's face.
    ``floor`` is added everywhere (every pixel has some weight)."""
    v = np.asarray(visibility)
    v = v.astype(np.float32) / 255.0 if v.dtype == np.uint8 else v.astype(np.float32)
    lead = v.shape[:-2]
    H, W = v.shape[-2:]
    flat = v.reshape(-1, H, W)
    pts = None
    if points68 is not None:
        pts = np.asarray(points68, np.float64).reshape(-1, 68, 2)
        if len(pts) != len(flat):
            raise BadInputError(f"{len(pts)} landmark sets for {len(flat)} visibility maps")
    s = feather * W / CANONICAL_SIZE[0]
    out = np.empty_like(flat)
    for i, vi in enumerate(flat):
        own = cv2.GaussianBlur(vi, (0, 0), s) if s > 0 else vi
        c = own + np.float32(mirror_weight) * (1.0 - own) * own[:, ::-1]
        if pts is not None:
            from .masks import face_mask

            c = c * (np.float32(outside_face) + np.float32(1.0 - outside_face) * face_mask(pts[i], (H, W)))
        out[i] = c + np.float32(floor)
    return out.reshape(lead + (H, W))


def rotate_face(
    image: np.ndarray,
    points68,
    *,
    yaw: float = 0.0,
    pitch: float = 0.0,
    roll: float = 0.0,
    focal: float | None = None,
) -> np.ndarray:
    """Re-render the photo with the head turned by (yaw, pitch, roll) degrees about
    HEAD_CENTRE_MM, using the generic surface as the face's shape (view synthesis with the
    frontalization machinery; used to make posed test photos). The whole image moves with
    the extended surface; regions hidden in the photo are stretched, not invented."""
    img = _check_image(image)
    p = _check_points(points68)
    h, w = img.shape[:2]
    src = estimate_head_pose(p, img.shape, focal=focal)
    r_new = src.R @ rotation_from_angles(yaw, pitch, roll)
    c = np.asarray(HEAD_CENTRE_MM)
    t_new = src.R @ c + src.tvec - r_new @ c
    # a dense frontal sampling of the (extended) surface, ~1.25 samples per photo pixel, covering the photo
    ppm = src.pixels_per_mm
    scale = 1.25 * ppm
    span = 1.3 * max(h, w) / ppm  # mm
    n = int(min(2400, math.ceil(span * scale)))
    frame = CanonicalFrame((n, n), n / span, (n - 1) / 2, (n - 1) / 2)
    surf = surface_on_frame(frame)
    xyz = surf.xyz.reshape(-1, 3)
    cam = xyz @ r_new.T + t_new
    pix = cam @ src.K.T
    ok = cam[:, 2] > 1.0
    uv = pix[ok, :2] / pix[ok, 2:3]
    z = cam[ok, 2]
    xyz = xyz[ok]
    q = np.rint(uv).astype(np.int64)
    keep = (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
    q, z, xyz = q[keep], z[keep], xyz[keep]
    key = q[:, 1] * w + q[:, 0]
    order = np.lexsort((z, key))  # front-most sample first in each pixel
    key, xyz = key[order], xyz[order]
    first = np.r_[True, key[1:] != key[:-1]]
    model = np.full((h * w, 3), np.nan)
    model[key[first]] = xyz[first]
    model = model.reshape(h, w, 3)
    hole = np.isnan(model[..., 0])
    if hole.any() and not hole.all():
        from scipy import ndimage

        idx = ndimage.distance_transform_edt(hole, return_distances=False, return_indices=True)
        model = model[idx[0], idx[1]]
    mp = src.project(model).astype(np.float32)
    return cv2.remap(img, mp[..., 0], mp[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
