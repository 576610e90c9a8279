"""The driver's motion in the canonical frame (Tom Hanks §4; steps 2-5 of :mod:`facetex.puppet.driver`):
head poses, the translation field on the depth-map grid, the expression fiducials, and the landmark
fields (lips, brows, lids) the puppet's grid follows."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import BadInputError
from ..landmarks import eye_centres, eye_distance
from .driver import (
    _MOUTH_FIDUCIALS,
    DriverParams,
    DriverTrack,
    GridInterpolator,
    fill_lost,
    generalized_procrustes,
    mouth_opening,
    similarity_procrustes,
    shot_starts,
    smooth_series,
)

__all__ = [
    "DriverMotion",
    "driver_motion",
    "LipFields",
    "BrowFields",
    "brow_heights",
    "mouth_lift",
    "lips_at_lift",
    "LidFields",
    "eye_openness",
    "unfold_columns",
    "MouthCorrection",
]


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
    landmarks the canonical frame is fitted to; shots (N,): each frame's shot of an edited clip
    (0, 1, ... from :func:`~facetex.puppet.driver.shot_starts`; nothing is smoothed across a cut)."""

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
    shots: np.ndarray | None = field(repr=False, default=None)
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
        iod = eye_distance(p)
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
    a, b = eye_centres(p)
    e = b - a
    iod = np.maximum(np.linalg.norm(e, axis=-1, keepdims=True), 1e-9)
    n = np.stack([e[..., 1], -e[..., 0]], axis=-1) / iod  # unit normal pointing up (y down)
    d = p[..., 17:27, :] - ((a + b) / 2)[..., None, :]
    return (d * n[..., None, :]).sum(axis=-1) / iod


def mouth_lift(points68) -> np.ndarray:
    """Height (...,) of the mouth corners (48, 54) above the middle of the inner lips (62, 66), over
    the eye-centre distance, for (..., 68, 2) landmarks (image y down): > 0 corners up (a smile)."""
    p = np.asarray(points68, np.float64)
    iod = eye_distance(p)
    mid = (p[..., 62, 1] + p[..., 66, 1]) / 2
    return (mid - (p[..., 48, 1] + p[..., 54, 1]) / 2) / np.maximum(iod, 1e-9)


def lips_at_lift(points68, lift: float, *, spread: tuple[float, float] = (10.0, 90.0),
                 lower_only: bool = False) -> np.ndarray:
    """(68, 2) motion of the lip landmarks (48-67; the rest 0) that takes a collection's mean
    landmarks to its lips at mouth-corner lift ``lift`` (:func:`mouth_lift`, clamped to the
    ``spread`` percentiles of its photos' lifts): per lip coordinate, the least-squares line of the
    photos' (n, 68, 2) ``points68`` on their lifts, from the mean lift to ``lift``. The line carries
    the collection's own mouth with the smile (a smile also widens it; r 0.55-0.94 between lift and
    width on the LFW collections), and the clamp keeps it within the mouths it has shown.
    ``lower_only``: no motion for a ``lift`` above the photos' mean (the lips only come down)."""
    p = np.asarray(points68, np.float64)
    if p.ndim != 3 or p.shape[1:] != (68, 2) or len(p) < 3:
        raise BadInputError(f"need (n >= 3, 68, 2) landmarks for the lips' lift line, got {p.shape}")
    lifts = mouth_lift(p)
    lo, hi = np.percentile(lifts, spread)
    dl = lifts - lifts.mean()
    move = np.zeros((68, 2))
    if float(dl @ dl) <= 1e-12:
        return move
    lips = p[:, 48:68] - p[:, 48:68].mean(axis=0)
    slope = np.einsum("n,nij->ij", dl, lips) / float(dl @ dl)
    if lower_only:
        lift = min(float(lift), float(lifts.mean()))
    move[48:68] = slope * (float(np.clip(lift, lo, hi)) - lifts.mean())
    return move


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
    shots = np.cumsum(shot_starts(track.points68, found))  # nothing is smoothed or filled across a cut
    mesh = fill_lost(track.mesh, found, segments=shots)
    p68 = fill_lost(track.points68, found, segments=shots)
    mean, s, R, t = generalized_procrustes(mesh[found], iters=params.procrustes_iters)
    # pose of every frame (interpolated for lost frames; rotation by its rotation vector)
    from scipy.spatial.transform import Rotation

    n = len(found)
    rv = np.zeros((n, 3))
    rv[found] = Rotation.from_matrix(R).as_rotvec()
    ls, tt = np.zeros(n), np.zeros((n, 3))
    ls[found], tt[found] = np.log(s), t
    rv, ls, tt = (fill_lost(a, found, segments=shots) for a in (rv, ls, tt))
    aligned = np.einsum("nij,nvj->nvi", Rotation.from_rotvec(rv).as_matrix().transpose(0, 2, 1),
                        mesh - tt[:, None]) / np.exp(ls)[:, None, None]
    w, o = params.smooth_window, params.smooth_order
    aligned = smooth_series(aligned, w, o, segments=shots)
    rv, ls, tt = (smooth_series(a, w, o, segments=shots) for a in (rv, ls, tt))
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
    filled = fill_lost(fid68, found, segments=shots)
    fid68 = smooth_series(filled, w, o, segments=shots)
    if params.lip_smooth_window != w:
        mouth_pts = list(_MOUTH_FIDUCIALS)
        fid68[:, mouth_pts] = smooth_series(filled[:, mouth_pts], params.lip_smooth_window, o, segments=shots)
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
                        mouth=mouth, fiducials68=fid68, triangles=triangles, frontal_mean68=fid_mean,
                        shots=shots)


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
