"""Aligning a persona's photos to its neutral frame (Tom Hanks Sec. 5): TPS sampling maps (Eq. 1),
resampling, the rank-k appearance subspace and the collection flow. Below both the collection
(:mod:`facetex.persona.collection`, which builds and stores the alignment) and the texture synthesis
(:mod:`facetex.persona.texture`, which composes it with a target's TPS)."""

from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

__all__ = ["tps_map", "tps_maps", "remap_stack", "compose_map_flow", "face_region", "appearance_subspace",
           "project_onto_subspace", "collection_flow", "quantize_flow", "TPS_GRID_STEP"]


def quantize_flow(flow: np.ndarray) -> np.ndarray:
    """float16 flow rounded to 1/256 px (|flow| < 128 px), the precision a .persona stores: below
    the 1/32 px sub-pixel grid of OpenCV's bilinear remap, and exact for float16 values >= 4 px."""
    return (np.clip(np.rint(np.asarray(flow, np.float32) * 256), -32767, 32767) / 256).astype(np.float16)


def _flow_star(args):
    from ..geometry.flow import optical_flow

    proj, warped, alpha, method = args
    return quantize_flow(optical_flow(proj, warped, alpha=alpha, method=method))


#: TPS maps are evaluated exactly on a grid every TPS_GRID_STEP px and bilinearly
#: interpolated (measured max error 0.24 px, mean 0.005 px at 192 x 240, lambda = 10):
#: ~20x faster than evaluating every pixel.
TPS_GRID_STEP = 4


def _tps_grid(shape, step: int):
    H, W = int(shape[0]), int(shape[1])
    gy = np.arange(-step, H + 2 * step, step, dtype=np.float64)
    gx = np.arange(-step, W + 2 * step, step, dtype=np.float64)
    xx, yy = np.meshgrid(gx, gy)
    mx, my = np.meshgrid(np.arange(W, dtype=np.float32) / step + 1, np.arange(H, dtype=np.float32) / step + 1)
    return np.stack([xx.ravel(), yy.ravel()], axis=1), (len(gy), len(gx)), mx, my


def tps_map(target, source, shape, smoothing: float, *, step: int = TPS_GRID_STEP) -> np.ndarray:
    """(H, W, 2) float32 TPS sampling map: target-frame pixel -> source pixel (Eq. 1), fitted
    with r(target) ~ source (``ThinPlateSpline``) and evaluated on a ``step`` px grid."""
    return tps_maps(np.asarray(source, np.float64)[None], target, shape, smoothing, step=step)[0]


def tps_maps(fiducials: np.ndarray, target: np.ndarray, shape, smoothing: float, *,
             step: int = TPS_GRID_STEP) -> np.ndarray:
    """(n, H, W, 2) float32 TPS sampling maps: target-frame pixel -> photo-i pixel (Eq. 1).

    All n splines share the target points, so they are fitted and evaluated together
    (:func:`facetex.geometry.tps.tps_evaluate_many`)."""
    from ..geometry.tps import tps_evaluate_many

    H, W = int(shape[0]), int(shape[1])
    grid, gshape, mx, my = _tps_grid((H, W), step)
    out = np.empty((len(fiducials), H, W, 2), np.float32)
    for i0 in range(0, len(fiducials), 64):  # bounds the (64, grid, 2) float64 block
        G = tps_evaluate_many(target, fiducials[i0:i0 + 64], grid, smoothing=smoothing)
        for j, g in enumerate(G.reshape(-1, *gshape, 2).astype(np.float32)):
            out[i0 + j] = cv2.remap(g, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out


def remap_stack(images: np.ndarray, maps: np.ndarray) -> np.ndarray:
    """Sample every image i at maps[i] (bilinear, border replicate); float32 out."""
    out = np.empty(maps.shape[:3] + images.shape[3:], np.float32)
    for i in range(len(images)):
        im = images[i]
        if im.dtype != np.float32:
            im = im.astype(np.float32) * (1 / 255.0 if im.dtype == np.uint8 else 1.0)
        out[i] = cv2.remap(im, maps[i, ..., 0], maps[i, ..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out


def compose_map_flow(maps: np.ndarray, flows: np.ndarray) -> np.ndarray:
    """maps[i](x + flows[i](x)): one sampling map per photo (warp after warp, one resampling)."""
    H, W = maps.shape[1:3]
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)
    out = np.empty_like(maps)
    for i in range(len(maps)):
        f = flows[i].astype(np.float32)
        out[i] = cv2.remap(maps[i], xs + f[..., 0], ys + f[..., 1], cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE)
    return out


def face_region(points68_mean: np.ndarray, shape) -> np.ndarray:
    """bool (H, W) face region (jaw + forehead arc) where the appearance subspace is fitted."""
    from ..geometry.masks import face_mask

    return face_mask(points68_mean, shape) > 0.5


def appearance_subspace(stack: np.ndarray, region: np.ndarray, rank: int) -> tuple[np.ndarray, np.ndarray]:
    """Rank-``rank`` appearance subspace (mean + ``rank`` principal components, centred SVD
    restricted to ``region``) of an (n, H, W, 3) stack, and the projections of the stack
    onto it. Returns (subspace (1 + rank, H, W, 3), projections (n, H, W, 3))."""
    n, H, W, C = stack.shape
    X = stack.reshape(n, -1)
    mu = X.mean(axis=0)
    Xc = X - mu
    m = np.repeat(region.reshape(-1), C)
    Xm = Xc[:, m].astype(np.float64)
    G = Xm @ Xm.T  # n x n Gram: cheaper than an SVD of the n x pixels matrix
    evals, evecs = np.linalg.eigh(G)
    k = min(rank, n - 1)
    U = evecs[:, ::-1][:, :k]
    s = np.sqrt(np.maximum(evals[::-1][:k], 1e-12))
    basis = ((U / s).T @ Xc).astype(np.float32)  # orthonormal inside the region
    proj = (mu + (U @ (U.T @ Xc))).astype(np.float32)
    sub = np.zeros((rank + 1, H * W * C), np.float32)
    sub[0] = mu
    sub[1 : k + 1] = basis
    return sub.reshape(rank + 1, H, W, C), proj.reshape(n, H, W, C)


def project_onto_subspace(image: np.ndarray, subspace: np.ndarray, region: np.ndarray) -> np.ndarray:
    """Least-squares projection of one (H, W, 3) image onto ``subspace`` (mean + components),
    coefficients fitted inside ``region``."""
    mu = subspace[0].reshape(-1)
    B = subspace[1:].reshape(len(subspace) - 1, -1)
    m = np.repeat(region.reshape(-1), subspace.shape[-1])
    y = image.reshape(-1).astype(np.float32) - mu
    c = np.linalg.lstsq(B[:, m].T.astype(np.float64), y[m].astype(np.float64), rcond=None)[0]
    return (mu + c.astype(np.float32) @ B).reshape(image.shape).astype(np.float32)


def collection_flow(stack: np.ndarray, proj: np.ndarray, params, *, pool=None,
                    progress: Callable | None = None) -> np.ndarray:
    """(n, H, W, 2) float16 flows (1/256 px, :func:`quantize_flow`) from each projection to its photo:
    warping photo i with flow i pulls it onto its illumination-matched projection (Tom Hanks Sec. 5).
    ``params``: a :class:`facetex.persona.PersonaParams` (``flow_alpha``, ``flow_method``); ``pool``:
    a worker pool with ``map(func, items, progress=, stage=)``, default this process."""
    items = [(proj[i], stack[i], params.flow_alpha, params.flow_method) for i in range(len(stack))]
    if pool is not None:  # the build's worker pool (facetex.persona.collection)
        return np.stack(pool.map(_flow_star, items, progress=progress, stage="flow"))
    out = []
    for item in items:
        out.append(_flow_star(item))
        if progress:
            progress(n=1, stage="flow")
    return np.stack(out)
