"""SIFT-flow-like dense alignment of faces of different people (FaceTex §2.3, Liu et al. 2011).

Hand-written (no library offers SIFT flow). Descriptors: scikit-image's dense
DAISY by default -- on real faces it gave 4-7% lower error than dense SIFT both
for a known warp and across people (benchmarks/geometry_flow.py) -- or dense
SIFT as in the paper (``descriptor="sift"``; built here from oriented-gradient
channels pooled with bilinear cell weights as vlfeat's dsift, since OpenCV's
SIFT.compute on a 65k-keypoint grid is far slower). Both are projected on their
joint 32 leading principal components, which also cuts the matching cost 4x.
Matching is a coarse-to-fine discrete labelling with SIFT flow's energy::

    E(w) = Σ_p min(|s_a(p) - s_b(p + w(p))|_1, t)                 data
         + Σ_p η (|u(p)| + |v(p)|)                                small displacement
         + Σ_(p,q) min(λ|u(p) - u(q)|, τ) + min(λ|v(p) - v(q)|, τ)   truncated-L1 smoothness

SIFT flow optimises E by dual-layer belief propagation; here it is optimised
per pyramid level by semi-global aggregation (Hirschmüller 2008) over four
scanline directions (exact min-convolution with the truncated-L1 term, split
into its two components), with labels a (2r+1)² window around the upsampled
coarser flow. The final level is refined to sub-pixel by a parabola
fit of the aggregated cost.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import BadInputError
from ._flow_core import gray01



@dataclass(frozen=True)
class SiftFlowParams:
    """Defaults for :func:`sift_flow` (descriptor distances are L1 of unit-norm descriptors)."""

    descriptor: str = "daisy"  # "daisy" (scikit-image DAISY, radius 2*cell) or "sift" (dense SIFT, as SIFT flow)
    cell: int = 4            # SIFT cell size in pixels (4x4 cells, 8 orientations -> 128-D)
    pca_dims: int = 32       # descriptors projected on their joint principal components (0: keep all)
    data_trunc: float = 3.0  # t: data-term truncation (median cross-person cost ≈ 1.6 DAISY, 2.3 SIFT)
    lam: float = 0.1         # λ: smoothness weight per pixel of flow difference
    tau: float = 1.0         # τ: smoothness truncation (reached at a 10 px jump)
    eta: float = 0.002       # η: small-displacement weight per pixel
    radius: int = 2          # r: search window radius around the upsampled flow (finer levels)
    coarse_radius: int = 5   # search radius at the coarsest level
    min_size: int = 24       # coarsest pyramid level's smaller side


def _gray(img: np.ndarray, name: str) -> np.ndarray:
    return gray01(img, name, 8)


def _dense_sift_cf(gray: np.ndarray, cell: int) -> np.ndarray:
    """Dense SIFT, channels first (128, H, W) -- the layout in which it is built and projected."""
    g = cv2.GaussianBlur(gray, (0, 0), 0.8)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=1) * 0.5
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=1) * 0.5
    mag = np.sqrt(gx * gx + gy * gy)
    pos = (np.arctan2(gy, gx) % (2 * np.pi)) * (8 / (2 * np.pi))
    # bilinear spatial pooling over a cell (vlfeat dsift's triangular window)
    tri = np.maximum(0, 1 - np.abs(np.arange(-cell + 1, cell)) / cell).astype(np.float32)
    tri /= tri.sum()
    h, w = g.shape
    offs = [int(round((i - 1.5) * cell)) for i in range(4)]
    pad = max(abs(o) for o in offs)
    sig = 2.0 * cell  # SIFT's Gaussian window, half the descriptor width
    desc = np.empty((4, 4, 8, h, w), np.float32)
    for b in range(8):
        d = np.abs(pos - b)
        wgt = np.maximum(0, 1 - np.minimum(d, 8 - d))  # soft orientation binning
        ch = cv2.sepFilter2D(mag * wgt, cv2.CV_32F, tri, tri, borderType=cv2.BORDER_REPLICATE)
        ch = cv2.copyMakeBorder(ch, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
        for i, oy in enumerate(offs):
            for j, ox in enumerate(offs):
                gw = np.exp(-((oy * oy + ox * ox) / (2 * sig * sig)))
                np.multiply(ch[pad + oy:pad + oy + h, pad + ox:pad + ox + w], gw, out=desc[i, j, b])
    desc = desc.reshape(128, h, w)
    # SIFT normalisation: unit length, clip at 0.2, renormalise; a floor on the norm
    # keeps flat skin from being amplified into noise
    norm = np.sqrt(np.einsum("chw,chw->hw", desc, desc))
    floor = 0.1 * float(norm.mean()) + 1e-8
    np.minimum(desc / np.maximum(norm, floor), 0.2, out=desc)
    norm = np.sqrt(np.einsum("chw,chw->hw", desc, desc))
    return desc / np.maximum(norm, 1e-8)


def dense_sift(gray: np.ndarray, cell: int = 4) -> np.ndarray:
    """128-D SIFT descriptor at every pixel (4x4 cells of ``cell`` px, 8 orientations), float32 (H, W, 128)."""
    return np.ascontiguousarray(_dense_sift_cf(np.asarray(gray, np.float32), cell).transpose(1, 2, 0))


def _dense_daisy_cf(gray: np.ndarray, radius: int = 8) -> np.ndarray:
    """scikit-image DAISY at every pixel (image edge-padded so the output keeps its size), (104, H, W)."""
    from skimage.feature import daisy

    g = cv2.copyMakeBorder(gray, radius, radius, radius, radius, cv2.BORDER_REPLICATE)
    d = daisy(g, step=1, radius=radius, rings=2, histograms=6, orientations=8, normalization="l2")
    return np.ascontiguousarray(d[: gray.shape[0], : gray.shape[1]].transpose(2, 0, 1), np.float32)


def _project(da: np.ndarray, db: np.ndarray, dims: int) -> tuple[np.ndarray, np.ndarray]:
    """Channels-first descriptors -> channels-last, optionally on their joint leading principal components."""
    c, h, w = da.shape
    xa, xb = da.reshape(c, -1), db.reshape(c, -1)
    if not 0 < dims < c:
        return (np.ascontiguousarray(xa.T).reshape(h, w, c), np.ascontiguousarray(xb.T).reshape(h, w, c))
    sample = np.concatenate([xa[:, ::11], xb[:, ::11]], axis=1)
    mean = sample.mean(axis=1, keepdims=True)
    centred = sample - mean
    _, vecs = np.linalg.eigh(centred @ centred.T)
    p = np.ascontiguousarray(vecs[:, ::-1][:, :dims].T, dtype=np.float32)     # (dims, c)
    proj = lambda x: np.ascontiguousarray((p @ (x - mean)).T).reshape(h, w, dims)  # noqa: E731
    return proj(xa), proj(xb)


def _resize_area(x: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """cv2.resize(INTER_AREA) of a many-channel image (cv2 handles at most 4 channels there)."""
    return np.concatenate([np.atleast_3d(cv2.resize(np.ascontiguousarray(x[..., i:i + 4]), size,
                                                    interpolation=cv2.INTER_AREA))
                           for i in range(0, x.shape[2], 4)], axis=2)


def _data_cost(da, db, u0, r, trunc, eta):
    """Cost volume (H, W, (2r+1)²) of truncated-L1 descriptor distances, labels u0 + (dx, dy)."""
    h, w, c = da.shape
    ys, xs = np.mgrid[0:h, 0:w]
    da2, db2 = da.reshape(-1, c), db.reshape(-1, c)
    cost = np.empty((h, w, (2 * r + 1) ** 2), np.float32)
    k = 0
    for dy in range(-r, r + 1):
        ty = np.clip(ys + u0[..., 1] + dy, 0, h - 1) * w
        for dx in range(-r, r + 1):
            idx = (ty + np.clip(xs + u0[..., 0] + dx, 0, w - 1)).ravel()
            l1 = cv2.reduce(cv2.absdiff(da2, np.take(db2, idx, axis=0)), 1, cv2.REDUCE_SUM)
            cost[..., k] = np.minimum(l1.reshape(h, w), trunc) + eta * (np.abs(u0[..., 0] + dx) + np.abs(u0[..., 1] + dy))
            k += 1
    return cost


def _kernel_table(r: int, lam: float, tau: float) -> tuple[np.ndarray, int]:
    """K[s + s_max, i, j] = min(λ|i + s - j|, τ): truncated-L1 cost between label i of p and j of q
    when the two windows are offset by s (the difference of their integer base flows)."""
    k = 2 * r + 1
    s_max = 2 * r + int(np.ceil(tau / max(lam, 1e-6))) + 1  # beyond this every entry is τ
    s = np.arange(-s_max, s_max + 1)[:, None, None]
    i, j = np.arange(k)[None, :, None], np.arange(k)[None, None, :]
    return np.minimum(lam * np.abs(i + s - j), tau).astype(np.float32), s_max


def _message(prev: np.ndarray, kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
    """min over q's labels (y', x') of L_q(y', x') + Kx[x, x'] + Ky[y, y'] for each label (y, x) of p.

    The truncated-L1 term is a sum over components, so the 2-D min-convolution
    splits into two 1-D ones (exact; SIFT flow's dual-layer BP exploits the same).
    The label axes are tiny, so the minima are unrolled (numpy reductions over a
    short inner axis are slow).
    """
    n = prev.shape[0]
    k = kx.shape[1]
    lq = prev.reshape(n, k, k)                                       # (n, y', x')
    a = lq[:, :, None, 0] + kx[:, None, :, 0]                        # (n, y', x)
    for j in range(1, k):
        np.minimum(a, lq[:, :, None, j] + kx[:, None, :, j], out=a)
    m = a[:, None, 0, :] + ky[:, :, 0, None]                         # (n, y, x)
    for j in range(1, k):
        np.minimum(m, a[:, None, j, :] + ky[:, :, j, None], out=m)
    return m.reshape(n, k * k)


def _aggregate(cost: np.ndarray, u0: np.ndarray, r: int, p: SiftFlowParams) -> np.ndarray:
    """Semi-global aggregation (Hirschmüller 2008) along rows and columns, both ways at once; summed costs."""
    ktab, s_max = _kernel_table(r, p.lam, p.tau)
    total = np.zeros_like(cost)
    for transpose in (False, True):
        c = cost.transpose(1, 0, 2) if transpose else cost
        u = u0.transpose(1, 0, 2) if transpose else u0
        acc = total.transpose(1, 0, 2) if transpose else total
        h, w = c.shape[:2]
        # forward (left->right) and backward passes stacked on the batch axis
        cc = np.concatenate([c, c[:, ::-1]], axis=0)
        uu = np.concatenate([u, u[:, ::-1]], axis=0)
        sh = np.clip(uu[:, 1:] - uu[:, :-1], -s_max, s_max) + s_max   # (2h, w-1, 2) offset p - q
        out = np.empty_like(cc)
        prev = out[:, 0] = cc[:, 0]
        for x in range(1, w):
            msg = _message(prev, ktab[sh[:, x - 1, 0]], ktab[sh[:, x - 1, 1]])
            prev = out[:, x] = cc[:, x] + msg - prev.min(axis=1, keepdims=True)
        acc += out[:h]
        acc += out[h:, ::-1]
    return total


def _subpixel(total: np.ndarray, best: np.ndarray, r: int) -> np.ndarray:
    """Parabola fit of the aggregated cost around the best label, per component, clamped to ±0.5."""
    h, w, _ = total.shape
    k = 2 * r + 1
    vol = total.reshape(h, w, k, k)
    by, bx = best // k, best % k
    ii, jj = np.mgrid[0:h, 0:w]
    c0 = vol[ii, jj, by, bx]
    out = np.zeros((h, w, 2), np.float32)
    for comp, b in ((0, bx), (1, by)):
        lo, hi = np.clip(b - 1, 0, k - 1), np.clip(b + 1, 0, k - 1)
        cm = vol[ii, jj, by, lo] if comp == 0 else vol[ii, jj, lo, bx]
        cp = vol[ii, jj, by, hi] if comp == 0 else vol[ii, jj, hi, bx]
        den = cm - 2 * c0 + cp
        ok = (b > 0) & (b < k - 1) & (den > 1e-6)
        out[..., comp] = np.clip(np.where(ok, 0.5 * (cm - cp) / np.maximum(den, 1e-6), 0), -0.5, 0.5)
    return out


def sift_flow(a: np.ndarray, b: np.ndarray, *, params: SiftFlowParams | None = None, progress=None, **overrides) -> np.ndarray:
    """Dense flow from ``a`` to ``b`` (``a(x) ≈ b(x + F(x))``) by SIFT-flow matching, float32 (H, W, 2).

    For faces of different people, roughly pre-aligned (landmark morph / similarity);
    ``warp_with_flow(b, F)`` then aligns b's contours to a. Keyword overrides set
    fields of :class:`SiftFlowParams` (e.g. ``lam=0.1``). ``progress(n=1, level=i)``
    is called once per pyramid level.
    """
    p = params or SiftFlowParams()
    if overrides:
        unknown = set(overrides) - set(SiftFlowParams.__dataclass_fields__)
        if unknown:
            raise BadInputError(f"unknown sift_flow parameter(s) {sorted(unknown)}: see SiftFlowParams")
        p = SiftFlowParams(**{**p.__dict__, **overrides})
    ga, gb = _gray(a, "a"), _gray(b, "b")
    if ga.shape != gb.shape:
        raise BadInputError(f"images differ in size: {ga.shape} vs {gb.shape}; resize one to the other")
    if p.descriptor == "sift":
        da, db = _dense_sift_cf(ga, p.cell), _dense_sift_cf(gb, p.cell)
    elif p.descriptor == "daisy":
        da, db = _dense_daisy_cf(ga, 2 * p.cell), _dense_daisy_cf(gb, 2 * p.cell)
    else:
        raise BadInputError(f"unknown descriptor {p.descriptor!r}: use 'sift' or 'daisy'")
    da, db = _project(da, db, p.pca_dims)
    h, w = ga.shape
    n_levels = 1
    while min(h, w) / 2 ** n_levels >= p.min_size:
        n_levels += 1
    flow = None
    for lev in range(n_levels - 1, -1, -1):
        size = (max(1, round(w / 2 ** lev)), max(1, round(h / 2 ** lev)))
        if lev:
            dal, dbl = _resize_area(da, size), _resize_area(db, size)
        else:
            dal, dbl = da, db
        if flow is None:
            u0 = np.zeros((size[1], size[0], 2), np.int64)
            r = p.coarse_radius
        else:
            up = cv2.resize(flow, size, interpolation=cv2.INTER_LINEAR)
            up *= np.array([size[0] / flow.shape[1], size[1] / flow.shape[0]], np.float32)
            u0 = np.rint(up).astype(np.int64)
            r = p.radius
        cost = _data_cost(dal, dbl, u0, r, p.data_trunc, p.eta * 2 ** lev)
        total = _aggregate(cost, u0, r, p)
        best = total.argmin(axis=2)
        k = 2 * r + 1
        flow = (u0 + np.stack([best % k - r, best // k - r], axis=-1)).astype(np.float32)
        if lev:
            # drop isolated outliers before upsampling
            flow = np.stack([cv2.medianBlur(np.ascontiguousarray(flow[..., i]), 3) for i in range(2)], axis=-1)
        else:
            flow += _subpixel(total, best, r)
        if progress is not None:
            progress(n=1, level=lev)
    return flow
