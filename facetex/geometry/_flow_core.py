"""Flow-field utilities (see :mod:`facetex.geometry.flow` for the convention)."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import BadInputError


_BORDERS = {"replicate": cv2.BORDER_REPLICATE, "constant": cv2.BORDER_CONSTANT}


def _check_flow(flow: np.ndarray, name: str = "flow") -> np.ndarray:
    flow = np.asarray(flow)
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise BadInputError(f"{name} must have shape (H, W, 2), got {flow.shape}: pass a (dx, dy) field")
    return flow.astype(np.float32, copy=False)


def _grid(h: int, w: int) -> np.ndarray:
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    return np.stack([xs, ys], axis=-1)


def map_from_flow(flow: np.ndarray) -> np.ndarray:
    """Absolute sampling map (H, W, 2) of (x, y): ``map(x) = x + flow(x)``."""
    flow = _check_flow(flow)
    return _grid(*flow.shape[:2]) + flow


def flow_from_map(map_xy: np.ndarray) -> np.ndarray:
    """Flow of an absolute sampling map (as used by cv2.remap): ``flow(x) = map(x) - x``."""
    map_xy = _check_flow(map_xy, "map_xy")
    return map_xy - _grid(*map_xy.shape[:2])


def warp_with_flow(image: np.ndarray, flow: np.ndarray, *, border: str = "replicate") -> np.ndarray:
    """Backward warp ``out(x) = image(x + flow(x))``, bilinear (cv2.remap).

    ``image`` is (H, W) or (H, W, C) of any channel count and keeps its dtype;
    ``border`` is "replicate" or "constant" (zeros outside). cv2.remap samples at
    1/32-pixel positions, so values are exact only up to |∇image| / 64.
    """
    flow = _check_flow(flow)
    image = np.asarray(image)
    if image.shape[:2] != flow.shape[:2]:
        raise BadInputError(f"image {image.shape[:2]} and flow {flow.shape[:2]} differ in size: resize one of them")
    if border not in _BORDERS:
        raise BadInputError(f"border must be one of {sorted(_BORDERS)}, got {border!r}")
    m = map_from_flow(flow)
    mx, my = np.ascontiguousarray(m[..., 0]), np.ascontiguousarray(m[..., 1])

    def remap(x):
        return cv2.remap(x, mx, my, cv2.INTER_LINEAR, borderMode=_BORDERS[border], borderValue=0)

    src = image if image.dtype in (np.uint8, np.uint16, np.float32, np.float64) else image.astype(np.float32)
    if src.ndim == 2 or src.shape[2] <= 4:
        out = remap(np.ascontiguousarray(src))
        if src.ndim == 3 and out.ndim == 2:  # cv2 drops a singleton channel axis
            out = out[..., None]
    else:  # cv2.remap handles at most 4 channels
        out = np.concatenate([np.atleast_3d(remap(np.ascontiguousarray(src[..., i:i + 4])))
                              for i in range(0, src.shape[2], 4)], axis=2)
    return out.astype(image.dtype, copy=False)


def compose_flows(f_ab: np.ndarray, f_bc: np.ndarray) -> np.ndarray:
    """Flow A->C from A->B and B->C: ``f_ac(x) = f_ab(x) + f_bc(x + f_ab(x))``.

    So ``warp(warp(C, f_bc), f_ab) ≈ warp(C, compose_flows(f_ab, f_bc))``
    (Tom Hanks §5 composes F_{I->Î} ∘ F_{Î^T->I^T} this way).
    """
    f_ab, f_bc = _check_flow(f_ab, "f_ab"), _check_flow(f_bc, "f_bc")
    if f_ab.shape != f_bc.shape:
        raise BadInputError(f"flows differ in shape: {f_ab.shape} vs {f_bc.shape}")
    return f_ab + warp_with_flow(f_bc, f_ab)


def invert_flow(flow: np.ndarray, *, iters: int = 30, tol: float = 1e-3) -> np.ndarray:
    """Inverse flow G (B->A) of F (A->B): ``G(y) = -F(y + G(y))``, by fixed-point iteration.

    Accurate where F is smooth and invertible (|∇F| < 1); ``compose_flows(F, G)``
    and ``compose_flows(G, F)`` are then ≈ 0.
    """
    flow = _check_flow(flow)
    inv = -flow
    for _ in range(iters):
        new = -warp_with_flow(flow, inv)
        delta = float(np.abs(new - inv).max()) if new.size else 0.0
        inv = new
        if delta < tol:
            break
    return inv


def flow_epe(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean end-point error ``mean ||a(x) - b(x)||_2`` over ``mask`` (bool or weights), in pixels."""
    a, b = _check_flow(a, "a"), _check_flow(b, "b")
    if a.shape != b.shape:
        raise BadInputError(f"flows differ in shape: {a.shape} vs {b.shape}")
    err = np.sqrt(((a.astype(np.float64) - b) ** 2).sum(axis=2))
    if mask is None:
        return float(err.mean())
    w = np.asarray(mask, dtype=np.float64)
    if w.shape != err.shape:
        raise BadInputError(f"mask {w.shape} does not match flow {err.shape[:2]}")
    if w.sum() <= 0:
        raise BadInputError("mask is empty: pass a mask with at least one nonzero pixel")
    return float((err * w).sum() / w.sum())


def gray01(img: np.ndarray, name: str, min_side: int = 2) -> np.ndarray:
    """Float32 luminance in [0, 1] of a gray (H, W[, 1]) or RGB (H, W, 3) float/uint8 image."""
    img = np.asarray(img)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3) or min(img.shape[:2]) < min_side:
        raise BadInputError(f"{name} must be a gray (H,W) or RGB (H,W,3) image of at least "
                            f"{min_side}x{min_side}, got shape {img.shape}")
    img = img.astype(np.float32) / 255 if img.dtype == np.uint8 else img.astype(np.float32, copy=False)
    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img

