"""Deformation transfer with magnitude adjustment (Tom Hanks §4, Figure 3).

Meshes are depth-map meshes: (H, W, 3) arrays of vertex positions on an image
grid (NaN or masked off the face), as made by :mod:`facetex.puppet.shape`.
The driver's per-frame deformation Δ = M_D^i − M̄_D is moved onto the puppet's
average mesh M_P, with its magnitude re-measured on the puppet's own geometry
(a bigger eye gets a bigger blink) and regularised by Huber-ROF denoising.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from ..errors import BadInputError
from ._rows import scatter_rows

__all__ = ["DeformParams", "huber_rof", "DeformationTransfer", "transfer_deformation", "invert_map"]


@dataclass(frozen=True)
class DeformParams:
    """Denoising of the magnitude field f (Tom Hanks §6, "Implementation details")."""

    weight: float = 1.0  # TV regularisation weight
    epsilon: float = 0.05  # Huber epsilon
    iters: int = 50  # Chambolle–Pock iterations: linear rate ~0.86 each; max change < 0.02 px after 50
    # Refine the nearest vertex M_D(s, t) to the point M_D(u, v) + Δ by the local tangent map of the
    # correspondence (False: the paper's nearest vertex only, which loses motions under half a grid step)
    subvertex: bool = True


def _check_mask(mask, shape) -> np.ndarray:
    if mask is None:
        return np.ones(shape, dtype=bool)
    m = np.asarray(mask, dtype=bool)
    if m.shape != shape:
        raise BadInputError(f"mask is {m.shape} but the field is {shape}")
    return m


def huber_rof(f, *, weight: float = 1.0, epsilon: float = 0.05, iters: int = 50, mask=None) -> np.ndarray:
    """ROF denoising with a Huber-norm TV term (Tom Hanks §4):

        u* = argmin_u  weight · Σ h_ε(|∇u|) + ½ Σ (u − f)²,
        h_ε(x) = x² / (2ε) if x ≤ ε else x − ε/2.

    ``f`` (H, W); ``mask`` (H, W) bool limits the smoothing to pixels inside it
    (no gradient across its border; pixels outside are returned unchanged).
    Solved with the linearly convergent primal-dual Algorithm 3 of Chambolle & Pock
    (2011, §5.2 and §6.2.2: both the data term and the Huber dual are strongly
    convex). Hand-written and vectorised: scikit-image's denoise_tv_chambolle and
    denoise_tv_bregman solve plain TV-ROF only, and no installed library has Huber-ROF.
    """
    f = np.asarray(f)
    if f.ndim != 2:
        raise BadInputError(f"huber_rof needs a 2-D field, got shape {f.shape}")
    mask = _check_mask(mask, f.shape)
    out = f.astype(np.float32, copy=True)
    if weight <= 0 or iters <= 0 or not mask.any():
        return out
    if epsilon < 0:
        raise BadInputError(f"Huber epsilon must be >= 0, got {epsilon}")
    ys, xs = np.nonzero(mask)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    m = mask[y0:y1, x0:x1]
    h, w = m.shape
    # flat row-major layout: x-neighbour at +1, y-neighbour at +w (contiguous slices are fastest)
    g = np.ascontiguousarray(out[y0:y1, x0:x1]).ravel()
    n = g.size
    # edges between two pixels inside the mask (Neumann border elsewhere)
    ex = np.zeros((h, w), dtype=np.float32)
    ey = np.zeros((h, w), dtype=np.float32)
    ex[:, :-1] = m[:, :-1] & m[:, 1:]
    ey[:-1, :] = m[:-1, :] & m[1:, :]
    ex, ey = ex.ravel(), ey.ravel()
    lip = np.sqrt(8.0)  # ‖∇‖
    gamma = 1.0  # strong convexity of the data term
    delta = epsilon / weight  # strong convexity of the dual of the Huber term
    accelerate = delta <= 0
    if accelerate:  # plain TV: Algorithm 2
        tau = sigma = 1.0 / lip
        theta = 1.0
    else:  # Algorithm 3
        mu = 2.0 * np.sqrt(gamma * delta) / lip
        tau, sigma, theta = mu / (2 * gamma), mu / (2 * delta), 1.0 / (1.0 + mu)
    # dual variable scaled to q = p / weight (|q| <= 1); the weight moves into the steps.
    # q = (q_x, q_y) as rows of one (2, n) array and step-invariant products precomputed: the
    # grids are small, so each numpy call's overhead counts more than its arithmetic
    u, u_new, ubar = g.copy(), np.empty_like(g), g.copy()
    q, grad, sq = (np.zeros((2, n), dtype=np.float32) for _ in range(3))
    div, nrm = np.zeros(n, dtype=np.float32), np.zeros(n, dtype=np.float32)
    e = np.stack([ex, ey])
    s_e = e * np.float32(sigma / weight)
    # float32: the same result as the float64 maximum rounded (rounding is monotonic), 5x faster
    inv_shrink = np.float32(1.0 + sigma * delta)
    c = 1.0 / (1.0 + tau)
    g_c = (g * (tau * c)).astype(np.float32)  # as np.multiply(..., out=float32)
    for _ in range(int(iters)):
        # dual: q = (q + σ/w ∇ū) s / max(1, |q + σ/w ∇ū| s) with s = 1 / (1 + σδ): Huber prox + projection
        np.subtract(ubar[1:], ubar[:-1], out=grad[0, :-1])
        np.subtract(ubar[w:], ubar[:-w], out=grad[1, :-w])
        grad *= s_e  # the tails never written are 0 (edge weight 0 there)
        q += grad
        np.multiply(q, q, out=sq)
        np.add(sq[0], sq[1], out=nrm)
        np.sqrt(nrm, out=nrm)
        np.maximum(nrm, inv_shrink, out=nrm)
        q /= nrm
        # primal: u' = (u + τ w div q + τ g) / (1 + τ)
        np.add(q[0], q[1], out=div)
        div[1:] -= q[0, :-1]
        div[w:] -= q[1, :-w]
        div *= tau * weight * c
        np.multiply(u, c, out=u_new)
        u_new += div
        u_new += g_c
        if accelerate:
            theta = 1.0 / np.sqrt(1.0 + 2 * gamma * tau)
            tau, sigma = theta * tau, sigma / theta
            s_e = e * np.float32(sigma / weight)
            inv_shrink = np.float32(1.0 + sigma * delta)
            c = 1.0 / (1.0 + tau)
            g_c = (g * (tau * c)).astype(np.float32)  # as np.multiply(..., out=float32)
        # over-relaxation ū = u' + θ (u' − u)
        np.subtract(u_new, u, out=ubar)
        ubar *= theta
        ubar += u_new
        u, u_new = u_new, u
    u, g = u.reshape(h, w), g.reshape(h, w)
    out[y0:y1, x0:x1] = np.where(m, u, g)
    return out


def _fill_nan(a: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Copy of a (H, W, C) with the invalid pixels set to their nearest valid pixel (for sampling)."""
    from scipy import ndimage

    if valid.all():
        return a.copy()
    _, (iy, ix) = ndimage.distance_transform_edt(~valid, return_indices=True)
    return a[iy, ix]


def _masked_gradient(a: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(d/dy, d/dx) of (H, W, C) ``a`` from its values inside ``mask`` only: central differences
    where both neighbours are inside, one-sided where one is, 0 where none (np.gradient on a
    nearest-filled array halves the derivative at the mask's edge: its tangent maps there
    doubled the motion of the face outline)."""
    a = np.asarray(a, np.float64)
    m = np.asarray(mask, bool)
    out = []
    for ax in (0, 1):
        n = a.shape[ax]
        lo = [slice(None)] * 2
        hi = [slice(None)] * 2
        lo[ax], hi[ax] = slice(0, n - 1), slice(1, n)
        lo, hi = tuple(lo), tuple(hi)
        step = a[hi] - a[lo]  # a[i + 1] - a[i], at i
        ok = m[hi] & m[lo]
        fwd = np.zeros_like(a)
        bwd = np.zeros_like(a)
        has_f = np.zeros(m.shape, bool)
        has_b = np.zeros(m.shape, bool)
        fwd[lo] = np.where(ok[..., None], step, 0.0)
        has_f[lo] = ok
        bwd[hi] = np.where(ok[..., None], step, 0.0)
        has_b[hi] = ok
        cnt = has_f.astype(np.float64) + has_b
        out.append((fwd + bwd) / np.maximum(cnt, 1.0)[..., None])
    return out[0], out[1]


def _splat_inverse(fwd: np.ndarray, mask: np.ndarray, shape, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """(inverse (H', W', 2) float64, covered (H', W') bool) by normalised convolution: every source
    pixel of ``mask`` puts its own (x, y) at its forward position (bilinear splat), numerator and
    weight are Gaussian-blurred (``sigma`` target px) and divided; target pixels no source reaches
    (weight < 0.05) take the value of the nearest covered one. Continuous wherever the map folds."""
    from scipy import ndimage

    hh, ww = shape
    ys, xs = np.nonzero(mask)
    p = fwd[ys, xs].astype(np.float64)
    src = np.stack([xs, ys], axis=1).astype(np.float64)
    x0, y0 = np.floor(p[:, 0]).astype(np.int64), np.floor(p[:, 1]).astype(np.int64)
    fx, fy = p[:, 0] - x0, p[:, 1] - y0
    num = np.zeros((hh * ww, 2))
    den = np.zeros(hh * ww)
    for dy in (0, 1):
        for dx in (0, 1):
            wgt = (fx if dx else 1 - fx) * (fy if dy else 1 - fy)
            xi, yi = x0 + dx, y0 + dy
            ok = (xi >= 0) & (xi < ww) & (yi >= 0) & (yi < hh)
            idx = yi[ok] * ww + xi[ok]
            den += np.bincount(idx, wgt[ok], minlength=hh * ww)
            for c in range(2):
                num[:, c] += np.bincount(idx, wgt[ok] * src[ok, c], minlength=hh * ww)
    num = num.reshape(hh, ww, 2)
    den = den.reshape(hh, ww)
    if sigma > 0:
        num = np.stack([cv2.GaussianBlur(num[..., c], (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
                        for c in range(2)], axis=-1)
        den = cv2.GaussianBlur(den, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
    covered = den > 0.05
    b = num / np.maximum(den, 1e-12)[..., None]
    if not covered.any():
        return np.zeros((hh, ww, 2)), covered
    if not covered.all():
        _, (iy, ix) = ndimage.distance_transform_edt(~covered, return_indices=True)
        b = b[iy, ix]
    return b, covered


def invert_map(forward, mask, shape, *, iters: int = 10, splat_sigma: float = 1.0, max_move: float = 1.5
               ) -> np.ndarray:
    """Inverse of a sampling map: ``forward`` (H, W, 2) gives for each source pixel (trusted
    inside ``mask``) its (x, y) position on a target grid of ``shape`` (H', W'); returns
    (H', W', 2) float32, the source position of every target pixel.

    Start: the forward map splatted backwards (normalised convolution, :func:`_splat_inverse`;
    target pixels outside the forward image take the nearest one's source). Then Newton
    iterations on F(B(y)) = y (F extended off the mask by its nearest value; steps of at most
    1 px), kept per pixel only where they lower the residual |F(B(y)) - y| and stay within
    ``max_move`` px of the start: where F is smooth this is accurate to ~1/32 px (the precision
    of cv2.remap); where it folds (a dense correspondence between two faces has small folds at
    flow discontinuities) F has no inverse, Newton wanders off (it used to end on the grid's
    corner, giving puppet vertices there zero motion: spikes in the mesh), and the splat's
    continuous average is kept. Hand-written: scattered-data interpolation (scipy
    LinearNDInterpolator) bridges concave gaps of the forward image with long triangles.
    """
    fwd = np.asarray(forward, dtype=np.float32)
    mask = np.asarray(mask, dtype=bool) & np.isfinite(fwd).all(axis=2)
    h, w = fwd.shape[:2]
    hh, ww = (int(v) for v in shape)
    f = _fill_nan(fwd, mask).astype(np.float32)
    b0, _ = _splat_inverse(f, mask, (hh, ww), splat_sigma)
    b0[..., 0] = np.clip(b0[..., 0], 0, w - 1)
    b0[..., 1] = np.clip(b0[..., 1], 0, h - 1)
    gy, gx = np.mgrid[0:hh, 0:ww].astype(np.float64)
    target = np.stack([gx, gy], axis=-1)
    jy, jx = np.gradient(f, axis=(0, 1))  # (H, W, 2) each: dF/dy, dF/dx
    jac = np.concatenate([jx, jy], axis=2).astype(np.float32)  # Fx_x, Fy_x, Fx_y, Fy_y

    def residual(b):
        fb = cv2.remap(f, b[..., 0].astype(np.float32), b[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        return target - fb

    b = b0.copy()
    for _ in range(int(iters)):
        bx, by = b[..., 0].astype(np.float32), b[..., 1].astype(np.float32)
        j = cv2.remap(jac, bx, by, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        r = residual(b)
        a11, a21, a12, a22 = j[..., 0], j[..., 1], j[..., 2], j[..., 3]
        det = a11 * a22 - a12 * a21
        det = np.where(np.abs(det) < 1e-6, 1e-6, det)
        step = np.stack([(a22 * r[..., 0] - a12 * r[..., 1]) / det, (a11 * r[..., 1] - a21 * r[..., 0]) / det],
                        axis=-1)
        n = np.linalg.norm(step, axis=-1, keepdims=True)
        b = b + step * np.minimum(1.0, 1.0 / np.maximum(n, 1e-12))
        b[..., 0] = np.clip(b[..., 0], 0, w - 1)
        b[..., 1] = np.clip(b[..., 1], 0, h - 1)
    r0 = np.linalg.norm(residual(b0), axis=-1)
    r1 = np.linalg.norm(residual(b), axis=-1)
    keep = (r1 < r0) & (np.linalg.norm(b - b0, axis=-1) <= max_move)
    return np.where(keep[..., None], b, b0).astype(np.float32)


class DeformationTransfer:
    """Transfer driver deformations onto a puppet mesh (Tom Hanks §4, Figure 3).

    driver_mesh (H, W, 3): the driver's average mesh M̄_D on its depth grid;
    puppet_mesh (H', W', 3): the puppet's average mesh M_P on its grid;
    correspondence (H, W, 2): the puppet-grid position (x', y') of every driver grid
    pixel (e.g. ``map_from_flow(F)`` of the flow F from the driver's to the puppet's
    2D average, which satisfies driver(x) ≈ puppet(x + F(x)));
    inverse (H', W', 2), optional: the driver-grid position of every puppet pixel
    (default: :func:`invert_map` of the correspondence).
    The KD-tree over the driver's vertices, the puppet mesh sampled through the
    correspondence and the inverse map are computed once here; each call costs a
    KD-tree query, the denoising and a remap.
    """

    def __init__(self, driver_mesh, puppet_mesh, correspondence, *, driver_mask=None, puppet_mask=None,
                 inverse=None, params: DeformParams = DeformParams()):
        md = np.asarray(driver_mesh, dtype=np.float64)
        mp = np.asarray(puppet_mesh, dtype=np.float64)
        corr = np.asarray(correspondence, dtype=np.float32)
        if md.ndim != 3 or md.shape[2] != 3 or mp.ndim != 3 or mp.shape[2] != 3:
            raise BadInputError(f"meshes must be (H, W, 3) grids, got {md.shape} and {mp.shape}")
        if corr.shape != md.shape[:2] + (2,):
            raise BadInputError(f"correspondence must be (H, W, 2) = {md.shape[:2] + (2,)}, got {corr.shape}")
        self.params = params
        self.shape_driver, self.shape_puppet = md.shape[:2], mp.shape[:2]
        dmask = _check_mask(driver_mask, md.shape[:2]) & np.isfinite(md).all(axis=2)
        pmask = _check_mask(puppet_mask, mp.shape[:2]) & np.isfinite(mp).all(axis=2)
        if dmask.sum() < 4 or pmask.sum() < 4:
            raise BadInputError("driver or puppet mesh has (almost) no valid vertices: check the masks")
        self.driver_mask, self.puppet_mask = dmask, pmask
        self.rows, self.cols = np.nonzero(dmask)
        self.flat = self.rows * md.shape[1] + self.cols
        self.driver_vertices = md[dmask]
        self.tree = cKDTree(self.driver_vertices)
        # a vertex moved by less than half the distance to its closest neighbour stays its own
        # nearest vertex (triangle inequality): those need no query
        self.stay_radius = 0.5 * self.tree.query(self.driver_vertices, k=2, workers=1)[0][:, 1]
        # M_P(u', v') of every driver vertex, sampled through the correspondence
        cx, cy = corr[dmask, 0], corr[dmask, 1]
        mp_filled = _fill_nan(mp, pmask).astype(np.float32)
        grid = cv2.remap(mp_filled, np.ascontiguousarray(corr[..., 0]), np.ascontiguousarray(corr[..., 1]),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        self.puppet_at_driver = grid[dmask]
        # tangent maps: residual r ≈ [D_u D_v] a on the driver  ->  [P_u P_v] a on the puppet
        inside_all = cv2.remap(pmask.astype(np.float32), np.ascontiguousarray(corr[..., 0]),
                               np.ascontiguousarray(corr[..., 1]), cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 0.5
        d_v, d_u = _masked_gradient(_fill_nan(md, dmask), dmask)
        p_v, p_u = _masked_gradient(grid, inside_all)
        jd = np.stack([d_u[dmask], d_v[dmask]], axis=2)  # (K, 3, 2)
        jp = np.stack([p_u[dmask], p_v[dmask]], axis=2)  # (K, 3, 2)
        self.tangent_map = jp @ np.linalg.pinv(jd)  # (K, 3, 3)
        inside = cv2.remap(pmask.astype(np.float32), cx[None], cy[None], cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=0)[0]
        self.corr_valid = inside > 0.5
        inv = invert_map(corr, dmask, mp.shape[:2]) if inverse is None else np.asarray(inverse, dtype=np.float32)
        if inv.shape != mp.shape[:2] + (2,):
            raise BadInputError(f"inverse must be (H', W', 2) = {mp.shape[:2] + (2,)}, got {inv.shape}")
        from scipy import ndimage

        _, (near_y, near_x) = ndimage.distance_transform_edt(~dmask, return_indices=True)
        self._near = (near_y * md.shape[1] + near_x).ravel()  # flat index of the nearest mask vertex
        self.inv_x = np.ascontiguousarray(inv[..., 0])
        self.inv_y = np.ascontiguousarray(inv[..., 1])
        self.puppet_mesh = mp

    def magnitudes(self, delta) -> tuple[np.ndarray, np.ndarray]:
        """(Δ̂ (K, 3), f (K,)) at the driver's mask vertices, before denoising."""
        d = np.asarray(delta, dtype=np.float64)
        if d.shape != self.shape_driver + (3,):
            raise BadInputError(f"delta must be (H, W, 3) = {self.shape_driver + (3,)}, got {d.shape}")
        # (K, 3) rows by np.take and per-column arithmetic: fancy indexing of short rows and
        # broadcasts over a length-3 axis are several times slower in numpy
        dk = np.nan_to_num(d.reshape(-1, 3).take(self.flat, axis=0))
        norm = np.sqrt(np.einsum("ij,ij->i", dk, dk))
        moving = norm > 1e-9
        dhat = np.zeros_like(dk)
        for c in range(3):
            np.divide(dk[:, c], norm, out=dhat[:, c], where=moving)
        # nearest driver vertex M_D(s, t) to M_D(u, v) + Δ(u, v)
        j = np.arange(len(dk))
        far = norm >= self.stay_radius
        j[far] = self.tree.query(self.driver_vertices[far] + dk[far], workers=1)[1]
        # Δ' = M_P(s', t') − M_P(u', v');  f = Δ̂ · Δ'  (Tom Hanks §4, Fig. 3)
        target = self.puppet_at_driver.take(j, axis=0)
        if self.params.subvertex:
            r = self.driver_vertices + dk - self.driver_vertices.take(j, axis=0)
            target = target + np.einsum("kij,kj->ki", self.tangent_map.take(j, axis=0), r)
        dprime = target - self.puppet_at_driver
        f = np.einsum("ij,ij->i", dhat, dprime)
        # no puppet counterpart: keep the driver's own magnitude
        off = ~(self.corr_valid & self.corr_valid[j])
        f[off] = norm[off]
        f[~moving] = 0.0
        return dhat, f

    def __call__(self, delta) -> np.ndarray:
        """Puppet mesh M_P^i (H', W', 3) for the driver deformation Δ (H, W, 3)."""
        p = self.params
        dhat, f = self.magnitudes(delta)
        field = np.zeros(self.shape_driver, dtype=np.float32)
        field.ravel()[self.flat] = f
        fstar = huber_rof(field, weight=p.weight, epsilon=p.epsilon, iters=p.iters, mask=self.driver_mask)
        fk = fstar.ravel()[self.flat]
        dk = np.empty(dhat.shape, np.float32)
        for c in range(3):  # (float64 products rounded to float32, as assigning dhat * fk would)
            np.multiply(dhat[:, c], fk, out=dk[:, c], casting="same_kind")
        disp = np.zeros(self.shape_driver + (3,), dtype=np.float32)
        scatter_rows(disp.reshape(-1, 3), self.flat, dk)
        # M_P^i = M_P + Δ̂ f*, carried to the puppet grid through the inverse correspondence
        # off the driver's mask (puppet vertices beyond the driver's face: jaw line, forehead) the
        # nearest driver vertex's motion, so the puppet's outline moves with the face instead of
        # staying behind
        disp = disp.reshape(-1, 3).take(self._near, axis=0).reshape(disp.shape)
        moved = cv2.remap(disp, self.inv_x, self.inv_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        out = self.puppet_mesh.copy()
        for c in range(3):
            np.add(out[..., c], moved[..., c], out=out[..., c], where=self.puppet_mask)
        return out


def transfer_deformation(driver_mesh, delta, puppet_mesh, correspondence, *, driver_mask=None, puppet_mask=None,
                         inverse=None, params: DeformParams = DeformParams()) -> np.ndarray:
    """One-shot :class:`DeformationTransfer`: the puppet mesh (H', W', 3) deformed like the driver."""
    return DeformationTransfer(driver_mesh, puppet_mesh, correspondence, driver_mask=driver_mask,
                               puppet_mask=puppet_mask, inverse=inverse, params=params)(delta)
