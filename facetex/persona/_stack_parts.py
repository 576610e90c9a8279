"""Building blocks of the precomputed texture stacks (:mod:`facetex.persona.stacks`): per-photo
confidence and pyramids, the photo rows, the sparse segments the blend multiplies, and the robust
product of a region's weights with them."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from .params import TextureParams
from .pyramid import gaussian_pyramid, laplacian_pyramid, laplacian_response

if TYPE_CHECKING:
    from .collection import Persona

__all__ = [
]


# ------------------------------------------------------------------ precomputation
def _confidence(persona: Persona, tp: TextureParams, photos: slice = slice(None)) -> np.ndarray:
    """(n, H, W) float32 confidence of the symmetry-filled frontal images ``photos``
    (:func:`facetex.geometry.frontalize.fill_confidence`; per photo)."""
    from ..geometry.frontalize import fill_confidence

    vis = persona.visibility[photos]
    if not tp.use_visibility:
        return np.ones(vis.shape, np.float32)
    return fill_confidence(vis, persona.points68[photos] if tp.face_support < 1 else None,
                           mirror_weight=tp.mirror_weight, outside_face=tp.face_support, floor=tp.visibility_floor)


def _pyramid_stack(aligned: np.ndarray, conf: np.ndarray, levels: int, tp: TextureParams,
                   out: list[np.ndarray] | None = None) -> list[np.ndarray]:
    """Per level k (finest first): (n, h_k * w_k * 4) float32 of [L' band (3 ch), L'] with
    L' = L^alpha * confidence, so a level of the blend is one matrix-vector product.
    ``out``: preallocated per-level (n, ...) arrays to fill."""
    n = len(aligned)
    stacks = out if out is not None else [None] * levels
    for i in range(n):
        pyr = laplacian_pyramid(aligned[i], levels)
        g = aligned[i]
        c = conf[i]
        for k in range(levels):
            if k > 0:
                if tp.alpha_ != 0:  # the image itself is needed only for the response
                    g = cv2.pyrDown(g)
                c = cv2.pyrDown(c)
            if tp.alpha_ == 0:  # L^0 = 1: the response is not needed
                L = np.array(c, np.float32)
            else:
                L = laplacian_response(g, blur=tp.laplacian_blur, floor=tp.laplacian_floor)
                if tp.alpha_ != 1:
                    L = L ** np.float32(tp.alpha_)
                L = L * c
            if stacks[k] is None:
                stacks[k] = np.empty((n, L.size * 4), np.float32)
            row = stacks[k][i].reshape(L.shape + (4,))
            row[..., :3] = pyr[k] * L[..., None]
            row[..., 3] = L
    return stacks


def _photo_rows(aligned: np.ndarray, conf: np.ndarray, levels: int, tp: TextureParams) -> list[np.ndarray]:
    """One photo's rows of :func:`_pyramid_stack`: per level (finest first) (h_k * w_k * 4,)
    float32 [L' band (3 ch), L'] (the same operations, so the same values)."""
    return [r[0] for r in _pyramid_stack(aligned[None], conf[None], levels, tp)]


def _photo_rows_rgbc(image_conf: np.ndarray, levels: int, tp: TextureParams,
                     work: dict | None = None) -> list[np.ndarray]:
    """:func:`_photo_rows` of a (H, W, 4) float32 [image, confidence] for alpha = 0 (L' = the
    confidence): one 4-channel Gaussian pyramid gives the image's and the confidence's levels
    (the separate pyramids' values up to float rounding, < 1e-6). ``work``: a dict kept between
    calls on same-sized images (one per thread): its buffers are reused (fresh ~1 MB arrays per
    photo cost page faults: 1.4-1.8x slower) and the rows returned are views into them, valid
    until the next call."""
    if tp.alpha_ != 0:
        return _photo_rows(image_conf[..., :3], image_conf[..., 3], levels, tp)
    if work is None:
        work = {}
    if work.get("shape") != (image_conf.shape, levels):
        g = gaussian_pyramid(image_conf, levels)
        work.update(shape=(image_conf.shape, levels), g=g, up=[np.empty_like(x) for x in g],
                    c=[np.empty(x.shape[:2], np.float32) for x in g], m=[np.empty_like(x) for x in g])
    g = work["g"]
    g[0] = np.asarray(image_conf, np.float32)
    for k in range(1, levels):
        cv2.pyrDown(g[k - 1], dst=g[k])
    rows = []
    for k in range(levels):
        h, w = g[k].shape[:2]
        # the 4-channel band, its last channel set to 1, times [c, c, c, c]: [band * c, c] in two
        # OpenCV calls (numpy's broadcast over a 3-channel view was 2-3x slower; same values)
        band = work["up"][k]
        if k < levels - 1:
            cv2.subtract(g[k], cv2.pyrUp(g[k + 1], dst=band, dstsize=(w, h)), dst=band)
        else:
            np.copyto(band, g[k])
        band[..., 3] = 1
        c = cv2.extractChannel(g[k], 3, dst=work["c"][k])
        rows.append(cv2.multiply(band, cv2.merge([c, c, c, c], dst=work["m"][k]), dst=band).reshape(-1))
    return rows


def _single_stack(images: np.ndarray, conf: np.ndarray, tp: TextureParams) -> np.ndarray:
    """(n, H * W * 4) float32 [L' image, L'] at full resolution (single-scale baselines)."""
    n = len(images)
    out = np.empty((n, images[0].shape[0] * images[0].shape[1] * 4), np.float32)
    for i in range(n):
        L = laplacian_response(images[i], blur=tp.laplacian_blur, floor=tp.laplacian_floor)
        if tp.alpha_ != 1:
            L = L ** np.float32(tp.alpha_)
        L = L * conf[i]
        row = out[i].reshape(L.shape + (4,))
        row[..., :3] = images[i] * L[..., None]
        row[..., 3] = L
    return out


def _float16_to_32(src: np.ndarray, out: np.ndarray) -> None:
    """``out[...] = src`` for a 2-D float16 ``src`` (OpenCV's SIMD conversion: 2-3x numpy's)."""
    if src.size == 0:
        return
    r = cv2.multiply(src, 1.0, dst=out, dtype=cv2.CV_32F)  # x * 1 is exact
    if r is not out:
        out[...] = r


def _gemv_blend(stack: np.ndarray, w: np.ndarray, shape) -> np.ndarray:
    r = (w @ stack).reshape(tuple(shape) + (4,))
    return r[..., :3] / np.maximum(r[..., 3:], 1e-30)


class _Segment:
    """Pixels of one pyramid level that belong to the same set of weight regions: their stack
    rows (n, npix * 4) float32 [L' band (3 ch), L'] stored contiguously (so a region's product
    reads only its own pixels), their flat pixel indices and the regions' masks there. ``stack``:
    the (n, npix * 4) float32 array to use (default: a new one)."""

    __slots__ = ("pixels", "cols", "regions", "stack", "masks")

    def __init__(self, pixels: np.ndarray, regions: tuple[int, ...], n: int, masks: np.ndarray,
                 stack: np.ndarray | None = None):
        self.pixels = pixels
        self.cols = (pixels[:, None] * 4 + np.arange(4)).reshape(-1)  # stack columns (4 per pixel)
        self.regions = regions
        self.stack = np.empty((n, len(pixels) * 4), np.float32) if stack is None else stack
        self.masks = np.repeat(masks, 4, axis=1)  # (len(regions), npix * 4) float32


def _small_page_arrays(shapes: list[tuple[int, int]]) -> list[np.ndarray]:
    """Float32 arrays of ``shapes`` in one anonymous memory map whose transparent
    huge pages are off. Why: numpy asks for huge pages for large arrays, and the kernel then
    compacts memory at the first touch (defrag "madvise"): the ~470 MB of a 519-photo persona's
    stacks cost 0.7-1.3 s of system time to fault in with huge pages, 0.2-0.5 s with 4 kB pages
    (the blends read them as fast). Where huge pages are only used on request (the usual
    "madvise" mode), the map's pages are made at once (``MAP_POPULATE``): one call instead of a
    fault per page, ~0.2 s less system time for those 470 MB. The arrays keep the map alive
    (their base); pickled, they are copied like any array."""
    import mmap

    sizes = [-(-int(np.prod(s)) * 4 // 64) * 64 for s in shapes]  # 64-byte aligned starts
    total = max(sum(sizes), 1)
    mem = None
    if hasattr(mmap, "MAP_POPULATE") and not _huge_pages_always():
        try:
            mem = mmap.mmap(-1, total, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS | mmap.MAP_POPULATE)
        except OSError:
            mem = None
    if mem is None:
        mem = mmap.mmap(-1, total)
    if hasattr(mmap, "MADV_NOHUGEPAGE"):
        try:
            mem.madvise(mmap.MADV_NOHUGEPAGE)
        except OSError:  # a kernel without transparent huge pages
            pass
    arrays, off = [], 0
    for s, size in zip(shapes, sizes):
        arrays.append(np.frombuffer(mem, np.float32, int(np.prod(s)), off).reshape(s))
        off += size
    return arrays


def _huge_pages_always() -> bool:
    """Whether the kernel backs every anonymous map with transparent huge pages (a populated map
    would then be made of them before it could be told not to)."""
    try:
        with open("/sys/kernel/mm/transparent_hugepage/enabled") as f:
            return "[always]" in f.read()
    except OSError:
        return False


def _csr(weights: np.ndarray):
    """Row-normalised weights (B, n) as a CSR matrix when sparse enough to pay off."""
    import scipy.sparse as sp

    return sp.csr_array(weights)


def _unpremultiply(r: np.ndarray) -> np.ndarray:
    """(..., 3) colours r[..., :3] / r[..., 3] of (..., 4) float32 rows [c * L', L'] (the
    channels one at a time: numpy broadcasts over a length-3 inner axis slowly)."""
    den = np.maximum(r[..., 3], np.float32(1e-30))
    out = np.empty(r.shape[:-1] + (3,), np.float32)
    for c in range(3):
        np.divide(r[..., c], den, out=out[..., c])
    return out


# ------------------------------------------------------------------ robust blend
#: the robust blend (``TextureParams.robust``) is used on the levels whose Eq. 3 uniform term is at
#: most this: the expression-weighted ones (not the shared lighting levels) ...
ROBUST_UNIFORM = 1e-3
#: ... from this level on (0 = the finest): the finest band (1-2 px: noise, JPEG, pores) is 4x the
#: pixels of the next and held no part of the ghosts it is for
ROBUST_FINEST = 1


def _robust_product(W, stack: np.ndarray, kappa: float) -> np.ndarray:
    """(B, cols) ``W @ stack`` ((B, n) weights, dense or sparse; (n, cols) premultiplied
    (band x c, c) pixel columns) with each photo's pixel weight times 1 / (1 + d^2 / (kappa s)^2):
    d = c |band - mean| (RGB; the plain weighted mean there, times the photo's confidence c), s^2
    the median of d^2 over the pixels it is sure of (c > 0.5) of the photos holding at least 5 %
    of the largest weight. A photo whose band disagrees with the others there (a hand or a
    microphone over the mouth) counts less. A Cauchy M-estimator's first reweighting step, by
    hand: the blend is a sparse product over precomputed stacks that no library's robust mean takes."""
    Wd = W.toarray() if hasattr(W, "toarray") else np.asarray(W)
    out = np.zeros((Wd.shape[0], stack.shape[1]), np.float32)
    for b in range(Wd.shape[0]):
        idx = np.flatnonzero(Wd[b])
        if idx.size == 0:
            continue
        w = Wd[b, idx].astype(np.float32)
        X = np.asarray(stack[idx], np.float32).reshape(idx.size, -1, 4)
        num = w @ X.reshape(idx.size, -1)
        num = num.reshape(-1, 4)
        mu = num[:, :3] / np.maximum(num[:, 3:], 1e-12)
        c = X[..., 3]
        r = X[..., :3] - c[..., None] * mu[None]
        d2 = np.einsum("ipc,ipc->ip", r, r)  # (photos, pixels)
        sure = (c > 0.5) & (w[:, None] >= 0.05 * w.max())
        s2 = float(np.median(d2[sure])) if sure.any() else 0.0
        if s2 <= 0:
            out[b] = num.reshape(-1)
            continue
        wr = w[:, None] / (1.0 + d2 * (1.0 / (kappa * kappa * s2)))
        out[b] = np.einsum("ip,ipc->pc", wr, X).reshape(-1)
    return out
