"""The generic 3D face and the canonical frontal frame used for frontalization.

Where it comes from (``facetex/data/generic_face.npz``, rebuilt by
``tools/build_generic_face.py``): the mean of MediaPipe 468-point face meshes of
the 60 frontal neutral portraits of the Face Research Lab London Set
(DeBruine & Jones 2017, doi:10.6084/m9.figshare.5047666.v5, CC BY 4.0),
aligned by generalised Procrustes analysis and averaged; triangulated by
Delaunay on the mean's frontal (x, y) with the slivers along the concave parts
of the outline dropped (MediaPipe's own tessellation is not shipped by any
installed package); the 68 iBUG points are dlib's 2D landmarks on the same
photos lifted onto each photo's mesh (barycentric z) and averaged. The model is
made left-right symmetric about x = 0 and scaled to millimetres (63 mm between
the eye centres, the adult mean interpupillary distance: "metric-ish", since
MediaPipe's z is only roughly in the scale of x and y). Axes follow the OpenCV
camera: x to the image right (the subject's left), y down, z away from the
camera; the origin is midway between the two eye centres (means of points
36-41 and 42-47).

The canonical frame is an orthographic frontal view of the model: canonical
pixel (u, v) = scale * (X, Y) + centre, with the model's eye centres at fixed
positions: on the row ``EYE_ROW * H``, ``EYE_SPAN * W`` apart, symmetric about
the middle column (W - 1) / 2, so the image's left-right mirror is the face's
mirror. Pixel centres are at integer coordinates.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import BadInputError, ModelNotFoundError

__all__ = [
    "GenericFace",
    "CanonicalFrame",
    "load_generic_face",
    "canonical_frame",
    "canonical_surface",
    "surface_on_frame",
    "CANONICAL_SIZE",
    "EYE_DISTANCE_MM",
    "FLIP68",
]

DATA_PATH = Path(__file__).resolve().parents[1] / "data" / "generic_face.npz"

#: Default canonical frame (W, H), close to the paper's ~194 x 244 face (Tom Hanks Sec. 8).
CANONICAL_SIZE = (192, 240)
#: Distance between the model's eye centres, mm.
EYE_DISTANCE_MM = 63.0
#: Canonical eye centres: (EYE_SPAN * W) apart, on row EYE_ROW * H.
EYE_SPAN = 0.36
EYE_ROW = 0.40

#: Smoothing (mm) of the depth extended off the mesh, and of the depth used for normals.
EXTENSION_SMOOTH_MM = 15.0
NORMAL_SMOOTH_MM = 2.0

#: Left-right mirror of the 68 iBUG points (0-based): point i of a face is point FLIP68[i] of its mirror image.
FLIP68 = np.array(
    list(range(16, -1, -1))  # jaw
    + list(range(26, 16, -1))  # brows
    + [27, 28, 29, 30, 35, 34, 33, 32, 31]  # nose
    + [45, 44, 43, 42, 47, 46, 39, 38, 37, 36, 41, 40]  # eyes
    + [54, 53, 52, 51, 50, 49, 48, 59, 58, 57, 56, 55]  # outer lip
    + [64, 63, 62, 61, 60, 67, 66, 65],  # inner lip
    dtype=np.intp,
)


@dataclass(frozen=True, eq=False)
class GenericFace:
    """The generic face model (units mm; see the module docstring).

    vertices (V, 3) float64, triangles (T, 3) int (counter-clockwise in the frontal
    image view), mirror (V,) the vertex of the mirror side, points68 (68, 3) the
    iBUG points, points68_std (68, 3) their spread over the build photos, depth
    the stored canonical depth map at CANONICAL_SIZE (NaN off the mesh).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    mirror: np.ndarray
    points68: np.ndarray
    points68_std: np.ndarray
    depth: np.ndarray
    provenance: str


@functools.lru_cache(maxsize=1)
def load_generic_face(path: str | Path | None = None) -> GenericFace:
    """Load ``facetex/data/generic_face.npz`` (cached; arrays read-only)."""
    p = Path(path) if path is not None else DATA_PATH
    if not p.is_file():
        raise ModelNotFoundError("generic face model missing: run python tools/build_generic_face.py", path=p)
    with np.load(p, allow_pickle=False) as z:
        arrays = dict(
            vertices=z["vertices"].astype(np.float64),
            triangles=z["triangles"].astype(np.intp),
            mirror=z["mirror"].astype(np.intp),
            points68=z["points68_3d"].astype(np.float64),
            points68_std=z["points68_3d_std"].astype(np.float64),
            depth=z["depth"].astype(np.float32),
        )
        provenance = str(z["provenance"])
    for a in arrays.values():
        a.setflags(write=False)
    return GenericFace(provenance=provenance, **arrays)


@dataclass(frozen=True)
class CanonicalFrame:
    """Orthographic frontal camera: (u, v) = scale * (X, Y) + (cx, cy); scale in px per mm."""

    size: tuple[int, int]
    scale: float
    cx: float
    cy: float

    def project(self, xyz: np.ndarray) -> np.ndarray:
        """(N, 2) canonical pixels of (N, 3) model points (orthographic: z is dropped)."""
        xyz = np.asarray(xyz, dtype=np.float64)
        return xyz[..., :2] * self.scale + np.array([self.cx, self.cy])

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) model (X, Y) of canonical pixels."""
        return (np.asarray(uv, dtype=np.float64) - np.array([self.cx, self.cy])) / self.scale


def canonical_frame(size=CANONICAL_SIZE) -> CanonicalFrame:
    """The canonical frame of ``size`` (W, H): eye centres at fixed fractions of the frame."""
    try:
        w, h = (int(v) for v in size)
    except (TypeError, ValueError):
        raise BadInputError(f"size must be (width, height), got {size!r}") from None
    if w < 16 or h < 16 or w > 4096 or h > 4096:
        raise BadInputError(f"canonical size must be between 16 and 4096 px per side, got {w}x{h}")
    return CanonicalFrame((w, h), EYE_SPAN * w / EYE_DISTANCE_MM, (w - 1) / 2.0, EYE_ROW * h)


def barycentric_lift(vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Lift (N, 2) (x, y) points onto a mesh seen along z: (N, 3) with z interpolated in the triangle
    under each point (the front-most, smallest z, if several); points off the mesh take z of the
    nearest triangle (barycentrics clamped). Hand-written: vectorised over all triangles."""
    v = np.asarray(vertices, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    a, b, c = (v[triangles[:, k]] for k in range(3))
    e1, e2 = b[:, :2] - a[:, :2], c[:, :2] - a[:, :2]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    det = np.where(np.abs(det) < 1e-12, 1e-12, det)
    d = p[:, None, :] - a[None, :, :2]  # (N, T, 2)
    l1 = (d[..., 0] * e2[:, 1] - d[..., 1] * e2[:, 0]) / det
    l2 = (e1[:, 0] * d[..., 1] - e1[:, 1] * d[..., 0]) / det
    l0 = 1.0 - l1 - l2
    lam = np.stack([l0, l1, l2], axis=-1)  # (N, T, 3)
    z = l0 * a[:, 2] + l1 * b[:, 2] + l2 * c[:, 2]
    worst = lam.min(axis=-1)
    inside = worst >= -1e-9
    out = np.empty((len(p), 3))
    out[:, :2] = p
    for i in range(len(p)):
        if inside[i].any():
            out[i, 2] = z[i][inside[i]].min()
        else:
            t = int(np.argmax(worst[i]))
            l = np.clip(lam[i, t], 0, None)
            l /= l.sum()
            out[i, 2] = l @ np.array([a[t, 2], b[t, 2], c[t, 2]])
    return out


def canonical_depth_from_mesh(vertices, triangles, frame: CanonicalFrame):
    """Depth Z (mm) of the mesh at every canonical pixel, (H, W) float64, and the on-mesh mask."""
    w, h = frame.size
    v = np.asarray(vertices, dtype=np.float64)
    uv = frame.project(v)
    return planar_interpolation(uv, v[:, 2], np.asarray(triangles), (w, h))


def planar_interpolation(xy, z, triangles, size) -> tuple[np.ndarray, np.ndarray]:
    """(values (H, W) float64, NaN off the mesh; mask) of the piecewise-planar interpolant of
    vertex values ``z`` over the 2-D triangles at every pixel centre of a (W, H) = ``size``
    grid: the plane of each triangle as matplotlib's LinearTriInterpolator computes it (the
    normal of its two edges from the first vertex), at the pixels inside it (edges included).
    Written with numpy: matplotlib.tri gives the same values but importing it costs ~0.5 s."""
    w, h = size
    p = np.column_stack([xy, z]).astype(np.float64)[np.asarray(triangles)]  # (T, 3 vertices, xyz)
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    out = np.full((h, w), np.nan)
    for t in np.flatnonzero(normal[:, 2] != 0):  # a triangle seen edge-on covers no area
        (x0, y0, _), (x1, y1, _), (x2, y2, _) = p[t]
        xa, xb = max(math.ceil(min(x0, x1, x2)), 0), min(math.floor(max(x0, x1, x2)), w - 1)
        ya, yb = max(math.ceil(min(y0, y1, y2)), 0), min(math.floor(max(y0, y1, y2)), h - 1)
        if xa > xb or ya > yb:
            continue
        gy, gx = np.mgrid[ya:yb + 1, xa:xb + 1].astype(np.float64)
        # the signs of the three edge functions agree inside (either orientation)
        e0 = (x1 - x0) * (gy - y0) - (y1 - y0) * (gx - x0)
        e1 = (x2 - x1) * (gy - y1) - (y2 - y1) * (gx - x1)
        e2 = (x0 - x2) * (gy - y2) - (y0 - y2) * (gx - x2)
        inside = ((e0 >= 0) & (e1 >= 0) & (e2 >= 0)) | ((e0 <= 0) & (e1 <= 0) & (e2 <= 0))
        n = normal[t]
        a, b, c = -n[0] / n[2], -n[1] / n[2], n @ p[t, 0] / n[2]
        out[ya:yb + 1, xa:xb + 1][inside] = (a * gx + b * gy + c)[inside]
    return out, np.isfinite(out)


@dataclass(frozen=True, eq=False)
class CanonicalSurface:
    """The generic surface sampled on a canonical frame.

    xyz (H, W, 3) model point of every canonical pixel (off the mesh: depth extended
    outwards from the nearest mesh pixel and smoothed, so hair and background are
    carried along); on_mesh (H, W) bool; normals (H, W, 3) unit, pointing to the
    camera (negative z); cos_frontal (H, W) the cosine between normal and the frontal
    view direction.
    """

    frame: CanonicalFrame
    xyz: np.ndarray
    on_mesh: np.ndarray
    normals: np.ndarray
    cos_frontal: np.ndarray

    def __post_init__(self):
        # flat float32 copies for the per-photo arithmetic of frontalize
        n = self.xyz.shape[0] * self.xyz.shape[1]
        flat = dict(
            xyz_flat=self.xyz.reshape(n, 3).astype(np.float32),
            normals_flat=self.normals.reshape(n, 3).astype(np.float32),
            cos_frontal_flat=np.maximum(self.cos_frontal.reshape(n), 0.1).astype(np.float32),
            # |grad Z| (mm per mm) = tan of the angle to the frontal view, capped
            slope_flat=np.minimum(np.sqrt(1.0 / np.maximum(self.cos_frontal.reshape(n), 0.1) ** 2 - 1.0), 10.0).astype(
                np.float32
            ),
        )
        for k, v in flat.items():
            v.setflags(write=False)
            object.__setattr__(self, k, v)


def canonical_surface(size=CANONICAL_SIZE) -> CanonicalSurface:
    """The generic surface on the canonical frame of ``size`` (cached per size)."""
    return surface_on_frame(canonical_frame(size))


@functools.lru_cache(maxsize=8)
def surface_on_frame(frame: CanonicalFrame) -> CanonicalSurface:
    """The generic surface sampled on any orthographic frontal frame (cached per frame)."""
    from scipy import ndimage

    g = load_generic_face()
    z, mask = canonical_depth_from_mesh(g.vertices, g.triangles, frame)
    if not mask.any():
        raise BadInputError(f"the canonical frame {frame} does not show the generic face")
    # extend outwards: nearest mesh depth, then smoothed off the mesh only (no cliff at the outline)
    dist, idx = ndimage.distance_transform_edt(~mask, return_indices=True)
    ext = z[idx[0], idx[1]]
    sigma = EXTENSION_SMOOTH_MM * frame.scale
    smooth = ndimage.gaussian_filter(ext, sigma, mode="nearest", truncate=3.0)
    a = np.clip(dist / 3.0, 0, 1)  # reach the smooth extension within 3 px of the outline
    z = np.where(mask, z, (1 - a) * ext + a * smooth)
    # normals of a lightly smoothed surface: the mesh is piecewise flat
    zn = ndimage.gaussian_filter(z, NORMAL_SMOOTH_MM * frame.scale, mode="nearest")
    w, h = frame.size
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    xy = frame.unproject(np.stack([uu, vv], axis=-1))
    xyz = np.concatenate([xy, z[..., None]], axis=-1)
    # surface normal of z = Z(x, y): (Z_x, Z_y, -1), facing the camera
    zy, zx = np.gradient(zn, 1.0 / frame.scale)
    n = np.stack([zx, zy, -np.ones_like(z)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    cos_f = np.ascontiguousarray(-n[..., 2])
    for a_ in (xyz, mask, n, cos_f):
        a_.setflags(write=False)
    return CanonicalSurface(frame, xyz, mask, n, cos_f)
