"""Average 3D face of a photo collection (Tom Hanks §4, after Kemelmacher-Shlizerman & Seitz 2011).

The frontalized, aligned photos of one person are treated as a photometric-stereo
stack: under a Lambertian first-order spherical-harmonic model every image is
``I_n(p) = l_n · [ρ(p), ρ(p) n(p)]``, so the gray intensity matrix M (N x P) has
rank 4 and factors as M = L S (lighting N x 4, "harmonic images" S 4 x P). The
factorization is unique only up to an invertible 4 x 4 A (M = L A⁻¹ · A S); A is
fixed here by fitting A S to the harmonic images of the generic 3D face (the
template of KS&S 2011), then the normals are integrated into a depth map.

Units: depth is in pixels of the canonical frame (x, y, z share a scale), z points
away from the camera (OpenCV axes, as the generic face), normals face the camera
(n_z < 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import BadInputError

__all__ = ["AverageShape", "reconstruct_average_shape", "generic_depth_px", "normals_from_depth",
           "integrate_normals", "checked_depth"]

#: Grazing normals are clipped to this |n_z| before integration (gradients bounded by ~10).
MIN_NZ = 0.1
#: Rec. 601 luma weights for the gray intensity matrix.
_LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float32)


@dataclass(frozen=True, eq=False)
class AverageShape:
    """Result of :func:`reconstruct_average_shape` on an (H, W) canonical grid.

    depth (H, W) float64, canonical px, NaN off the mask; normals (H, W, 3) unit,
    zero off the mask; albedo (H, W) relative (99th percentile = 1), zero off the
    mask; mask (H, W) bool; lighting (N, 4) first-order SH lighting of each photo
    in the same scale as the albedo.
    """

    depth: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray
    mask: np.ndarray
    lighting: np.ndarray

    def mesh(self, *, step: int = 1):
        """(vertices, faces, uv) of the depth map, see :func:`facetex.persona.mesh_io.depth_to_mesh`."""
        from .mesh_io import depth_to_mesh

        return depth_to_mesh(self.depth, self.mask, step=step)


def generic_depth_px(size) -> np.ndarray:
    """Depth (H, W) of the generic face in canonical pixels of the frame ``size`` (W, H)."""
    from ..geometry._generic_face import canonical_surface

    surf = canonical_surface(size)
    return surf.xyz[..., 2] * surf.frame.scale


def checked_depth(depth, region, size, max_error: float = 0.08) -> tuple[np.ndarray, str]:
    """(depth (H, W) float64 canonical px, source "collection" | "generic").

    ``depth`` (a reconstructed average, NaN off its mask, or None) is used when it is finite
    on more than half of ``region`` and its RMS difference to the generic face there is at
    most ``max_error`` x the frame width (too few or too uniformly lit photos give flat or
    bent surfaces); its holes are filled with the generic depth. Otherwise the generic
    face's depth of the frame ``size`` (W, H) is returned.
    """
    gen = generic_depth_px(size)
    region = np.asarray(region, dtype=bool)
    if depth is not None:
        d = np.asarray(depth, dtype=np.float64)
        if d.shape != gen.shape or region.shape != gen.shape:
            raise BadInputError(f"depth {d.shape} and region {region.shape} must be (H, W) = {gen.shape}")
        ok = region & np.isfinite(d)
        if ok.sum() > 0.5 * region.sum():
            rms = float(np.sqrt(np.mean((d[ok] - gen[ok]) ** 2)))
            if rms <= max_error * size[0]:
                return np.where(ok, d, gen), "collection"
    return gen.astype(np.float64), "generic"


def normals_from_depth(depth: np.ndarray) -> np.ndarray:
    """Unit normals (H, W, 3) of z = depth(x, y): (Z_x, Z_y, -1) normalised, facing the camera."""
    zy, zx = np.gradient(np.asarray(depth, dtype=np.float64))
    n = np.stack([zx, zy, -np.ones_like(zx)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def _gray_matrix(images: np.ndarray, mask: np.ndarray) -> np.ndarray:
    imgs = np.asarray(images)
    if imgs.ndim == 4 and imgs.shape[-1] == 3:
        imgs = imgs.astype(np.float32, copy=False) @ _LUMA
    elif imgs.ndim != 3:
        raise BadInputError(f"images must be (N, H, W, 3) or (N, H, W), got shape {imgs.shape}")
    if imgs.shape[1:] != mask.shape:
        raise BadInputError(f"images are {imgs.shape[1:]} but the mask is {mask.shape}: use one canonical frame")
    m = imgs[:, mask].astype(np.float64)
    if not np.isfinite(m).all():
        raise BadInputError("images hold NaN or inf inside the mask: fill or mask those pixels")
    return m


def _resolve_ambiguity(s: np.ndarray, n_ref: np.ndarray) -> np.ndarray:
    """4 x 4 A with A S ≈ ρ_ref [1, n_ref] per pixel, ρ_ref unknown (hand-written DLT).

    The unknown template albedo is eliminated: (A S)_k − n_k (A S)_0 = 0 for k = 1..3
    is linear and homogeneous in A's 16 entries; the least-squares A (‖A‖ = 1) is
    the smallest eigenvector of the 16 x 16 normal matrix.
    """
    p = s.shape[1]
    rows = np.zeros((3, p, 16))
    for k in range(3):
        rows[k, :, 0:4] = -n_ref[:, k, None] * s.T
        rows[k, :, 4 * (k + 1): 4 * (k + 2)] = s.T
    r = rows.reshape(3 * p, 16)
    _, vecs = np.linalg.eigh(r.T @ r)
    a = vecs[:, 0].reshape(4, 4)
    if np.median(a[0] @ s) < 0:  # albedo is positive
        a = -a
    return a


def integrate_normals(normals: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Depth (H, W) (NaN off ``mask``) whose gradients best match the normals, least squares.

    A sparse Poisson solve over the mask (scipy.sparse, SuperLU, ~0.5 s at 192 x 240), not Frankot–Chellappa:
    the face region is not rectangular and FFT integration assumes a periodic domain,
    which bends the depth near the outline. Each pair of 4-neighbours inside the mask
    gives one equation Z(q) − Z(p) = mean gradient; the free constant is fixed by a
    tiny ridge (mean ≈ 0 per connected region).
    """
    mask = np.asarray(mask, dtype=bool)
    n = np.asarray(normals, dtype=np.float64)
    nz = np.minimum(n[..., 2], -MIN_NZ)
    zx, zy = -n[..., 0] / nz, -n[..., 1] / nz
    h, w = mask.shape
    idx = -np.ones((h, w), dtype=np.int64)
    count = int(mask.sum())
    idx[mask] = np.arange(count)
    eqs_i, eqs_j, rhs = [], [], []
    for grad, (dy, dx) in ((zx, (0, 1)), (zy, (1, 0))):
        a = idx[: h - dy, : w - dx]
        b = idx[dy:, dx:]
        ok = (a >= 0) & (b >= 0)
        eqs_i.append(a[ok])
        eqs_j.append(b[ok])
        rhs.append(0.5 * (grad[: h - dy, : w - dx][ok] + grad[dy:, dx:][ok]))
    ia, ib, g = np.concatenate(eqs_i), np.concatenate(eqs_j), np.concatenate(rhs)
    e = len(g)
    rows = np.repeat(np.arange(e), 2)
    cols = np.stack([ia, ib], axis=1).ravel()
    vals = np.tile([-1.0, 1.0], e)
    d = sp.csr_matrix((vals, (rows, cols)), shape=(e, count))
    lhs = (d.T @ d + 1e-8 * sp.identity(count)).tocsc()
    # symmetric positive definite: minimum-degree ordering on A + A^T, no pivoting
    lu = spla.splu(lhs, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    z = lu.solve(d.T @ g)
    out = np.full((h, w), np.nan)
    out[mask] = z
    return out


def reconstruct_average_shape(images, mask, *, generic_depth=None, rank: int = 4,
                              resolve_ambiguity: bool = True) -> AverageShape:
    """Average depth of a stack of frontalized photos (N, H, W, 3) in [0, 1] over ``mask`` (H, W).

    ``generic_depth`` (H, W) is the template depth in canonical px (default: the
    generic face on the frame of this size). ``rank`` is the SVD rank kept (4 for
    first-order SH; the first 4 factors are used as the harmonic images).
    ``resolve_ambiguity=False`` reads the raw SVD factor as [ρ, ρn] (for comparison
    only: the normals are then meaningless).
    """
    mask = np.asarray(mask, dtype=bool)
    if mask.ndim != 2 or mask.sum() < 16:
        raise BadInputError(f"mask must be a 2-D boolean image with a face region, got shape {mask.shape}")
    if rank < 4:
        raise BadInputError(f"rank must be at least 4 (first-order spherical harmonics), got {rank}")
    m = _gray_matrix(images, mask)
    if m.shape[0] < rank:
        raise BadInputError(f"need at least {rank} photos for a rank-{rank} factorization, got {m.shape[0]}")
    h, w = mask.shape
    # Rank-4 factorization M = L S (KS&S 2011 Eq. 2)
    u, sv, vt = np.linalg.svd(m, full_matrices=False)
    root = np.sqrt(sv[:4])
    light = u[:, :4] * root
    s = root[:, None] * vt[:4]
    if resolve_ambiguity:
        ref = generic_depth_px((w, h)) if generic_depth is None else np.asarray(generic_depth, dtype=np.float64)
        if ref.shape != mask.shape:
            raise BadInputError(f"generic_depth is {ref.shape} but the mask is {mask.shape}")
        n_ref = normals_from_depth(np.nan_to_num(ref, nan=float(np.nanmean(ref))))[mask]
        a = _resolve_ambiguity(s, n_ref)
    else:
        a = np.eye(4)
    hs = a @ s  # [ρ, ρ n_x, ρ n_y, ρ n_z]
    light = light @ np.linalg.inv(a)
    rho_n = hs[1:].T
    nrm = np.linalg.norm(rho_n, axis=1, keepdims=True)
    nvec = rho_n / np.maximum(nrm, 1e-12)
    if not resolve_ambiguity and nvec[:, 2].mean() > 0:
        nvec = -nvec
    normals = np.zeros((h, w, 3))
    normals[mask] = nvec
    depth = integrate_normals(normals, mask)
    if resolve_ambiguity:  # absolute depth offset from the template
        depth[mask] += np.mean(ref[mask]) - np.mean(depth[mask])
    rho = np.clip(hs[0], 0.0, None)
    scale = max(float(np.percentile(rho, 99)), 1e-12)
    albedo = np.zeros((h, w))
    albedo[mask] = rho / scale
    return AverageShape(depth=depth, normals=normals, albedo=albedo, mask=mask, lighting=light * scale)
