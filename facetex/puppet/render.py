"""Z-buffered rasterization of textured triangle meshes (Tom Hanks §6: rendering the puppet).

Hand-written in vectorised numpy (per-triangle bounding boxes expanded into candidate
pixels, barycentric inside test, a z-buffer by ``np.minimum.at``) with OpenCV's
bilinear ``remap`` for the texture lookup. GPU renderers that install from PyPI
(pyrender, moderngl, open3d's OffscreenRenderer, vtk) need an OpenGL/EGL context
and a display-capable driver stack; pytorch3d has no wheel for the installed torch
and geometry/persona stay free of torch. This one runs anywhere numpy does.

Camera: vertices X in model coordinates (OpenCV axes: x right, y down, z away from
the camera) go to the camera as X_c = R X + t; a pinhole projects them to
``(focal * x_c / z_c + cx, focal * y_c / z_c + cy)``, a weak-perspective camera to
``(focal * x_c / t_z + cx, ...)``; (cx, cy) = ((W - 1) / 2, (H - 1) / 2) with pixel
centres at integer coordinates. Texture coordinates follow
:mod:`facetex.puppet.mesh_io` (u right, v down, texel edges at 0 and 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import BadInputError
from ._rows import scatter_rows

__all__ = ["Raster", "Layers", "project_vertices", "rasterize", "render_mesh", "render_layers", "vertex_normals",
           "interpolate_attributes"]

#: Candidate pixels per chunk of triangles (bounds the temporary memory to ~0.5 GB).
_CHUNK = 4_000_000
#: Points closer than this (model units) to the camera plane are not drawn (pinhole camera).
_NEAR = 1e-6


@dataclass(frozen=True, eq=False)
class Raster:
    """Per-pixel result of :func:`rasterize` on an (H, W) image.

    triangle (H, W) int64, index of the visible face or -1; bary (H, W, 3) float32
    perspective-correct barycentric weights of its three corners; depth (H, W)
    float64 camera z (inf where empty).
    """

    triangle: np.ndarray
    bary: np.ndarray
    depth: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        return self.triangle >= 0


def _size(size) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in size)
    except (TypeError, ValueError):
        raise BadInputError(f"size must be (width, height), got {size!r}") from None
    if not (1 <= w <= 16384 and 1 <= h <= 16384):
        raise BadInputError(f"image size must be 1..16384 px per side, got {w}x{h}")
    return w, h


def _camera(vertices, rotation, translation):
    """Checked float64 vertices (V, 3), rotation (3, 3) and translation (3,)."""
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise BadInputError(f"vertices must be (V, 3), got {v.shape}")
    r = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    t = np.zeros(3) if translation is None else np.asarray(translation, dtype=np.float64).reshape(3)
    if r.shape != (3, 3):
        raise BadInputError(f"rotation must be a 3x3 matrix, got {r.shape}")
    return v, r, t


def project_vertices(vertices, *, rotation=None, translation=None, focal: float, size,
                     weak_perspective: bool = False):
    """Screen positions (V, 2) and camera depths (V,) of model vertices (V, 3)."""
    v, r, t = _camera(vertices, rotation, translation)
    w, h = _size(size)
    x, y, z = _project(v, r, t, focal, w, h, weak_perspective)
    return np.stack([x, y], axis=1), z


def _project(v, r, t, focal, w, h, weak_perspective):
    """x, y, z (V,) each of :func:`project_vertices` (one column at a time: numpy broadcasts
    over a length-3 inner axis slowly)."""
    with np.errstate(invalid="ignore"):  # non-finite vertices are dropped by the callers
        cam = v @ r.T
    z = cam[:, 2] + t[2]
    if weak_perspective:
        if t[2] <= 0:
            raise BadInputError(f"weak perspective needs the mesh in front of the camera (t_z > 0), got {t[2]}")
        scale = focal / t[2]
        x = (cam[:, 0] + t[0]) * scale
        y = (cam[:, 1] + t[1]) * scale
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            x = focal * (cam[:, 0] + t[0]) / z
            y = focal * (cam[:, 1] + t[1]) / z
    x += (w - 1) / 2.0
    y += (h - 1) / 2.0
    return x, y, z


def rasterize(vertices, faces, *, rotation=None, translation=None, focal: float, size,
              weak_perspective: bool = False) -> Raster:
    """Visible face and barycentrics at every pixel centre of a (W, H) = ``size`` image."""
    f = np.asarray(faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise BadInputError(f"faces must be (F, 3), got {f.shape}")
    w, h = _size(size)
    v, r, t = _camera(vertices, rotation, translation)
    x, y, z = _project(v, r, t, focal, w, h, weak_perspective)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise BadInputError("faces index vertices that do not exist")
    # Puppet meshes have about one triangle per pixel, so numpy's per-call overhead on arrays of
    # ~15k dominates: everything stays in 1-D arrays (gathers/scatters of short rows and
    # broadcasts over short axes are several times slower), each test runs once per vertex,
    # and faces that cover no pixel centre get no candidates instead of being masked out.
    ok = (z > _NEAR) & np.isfinite(x) & np.isfinite(y)  # a face is drawn only if its corners are
    i0, i1, i2 = f[:, 0], f[:, 1], f[:, 2]
    tri_ids = None  # None: face k is face k (no face dropped)
    if not ok.all():
        tri_ids = np.flatnonzero(ok[i0] & ok[i1] & ok[i2])
        i0, i1, i2 = i0[tri_ids], i1[tri_ids], i2[tri_ids]
    x0, x1, x2, y0, y1, y2 = x[i0], x[i1], x[i2], y[i0], y[i1], y[i2]
    e1x, e1y, e2x, e2y = x1 - x0, y1 - y0, x2 - x0, y2 - y0
    det = e1x * e2y - e1y * e2x
    # pixel-centre bounding boxes, clipped to the image
    lox = np.maximum(np.ceil(np.minimum(np.minimum(x0, x1), x2) - 1e-9), 0)
    loy = np.maximum(np.ceil(np.minimum(np.minimum(y0, y1), y2) - 1e-9), 0)
    hix = np.minimum(np.floor(np.maximum(np.maximum(x0, x1), x2) + 1e-9), w - 1)
    hiy = np.minimum(np.floor(np.maximum(np.maximum(y0, y1), y2) + 1e-9), h - 1)
    keep = (np.abs(det) > 1e-12) & (hix >= lox) & (hiy >= loy)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # faces not kept: 0 candidates (their coefficients, possibly inf/NaN, are never read)
        # (box corners and sizes stay float64: exact integers, and float division is much faster)
        bw = np.where(keep, hix - lox + 1, 0)
        counts = (bw * np.where(keep, hiy - loy + 1, 0)).astype(np.int64)
        # λ1, λ2 as affine functions of the pixel (x, y): λ = a x + b y + c
        a1, b1 = e2y / det, -e2x / det
        a2, b2 = -e1y / det, e1x / det
        c1, c2 = -(a1 * x0 + b1 * y0), -(a2 * x0 + b2 * y0)
        # depth is affine in screen space (weak perspective), 1/z is (pinhole)
        zv = z if weak_perspective else 1.0 / z
    zc = (zv[i0], zv[i1], zv[i2])
    zbuf = np.full(h * w, np.inf)
    starts = np.zeros(len(counts) + 1, np.int64)
    np.cumsum(counts, out=starts[1:])
    if starts[-1] <= _CHUNK:
        chunk_edges = [0, len(counts)]
    else:
        chunk_edges = np.searchsorted(starts, np.arange(0, starts[-1] + _CHUNK, _CHUNK))
        chunk_edges = np.unique(np.clip(chunk_edges, 0, len(counts))).tolist()
    cand = []
    for c0, c1_ in zip(chunk_edges[:-1], chunk_edges[1:]):
        if c1_ <= c0:
            continue
        k = np.repeat(np.arange(c0, c1_), counts[c0:c1_])
        off = (np.arange(starts[c1_] - starts[c0]) - (starts[k] - starts[c0])).astype(np.float64)
        bwk = bw[k]
        dy = np.floor(off / bwk)  # exact: integers far below 2**53
        px = lox[k] + (off - dy * bwk)
        py = loy[k] + dy
        l1 = a1[k] * px + b1[k] * py + c1[k]
        l2 = a2[k] * px + b2[k] * py + c2[k]
        l0 = 1.0 - l1 - l2
        inside = np.flatnonzero((l0 >= -1e-7) & (l1 >= -1e-7) & (l2 >= -1e-7))
        k, l0, l1, l2 = k[inside], l0[inside], l1[inside], l2[inside]
        pix = (py[inside] * w + px[inside]).astype(np.int64)
        depth = l0 * zc[0][k] + l1 * zc[1][k] + l2 * zc[2][k]
        if not weak_perspective:
            depth = 1.0 / depth
        np.minimum.at(zbuf, pix, depth)
        cand.append((pix, k, depth, l0, l1, l2))
    tri = np.full(h * w, -1, dtype=np.int64)
    bary = np.zeros((h * w, 3), dtype=np.float32)
    for pix, k, depth, l0, l1, l2 in cand:
        win = np.flatnonzero(depth <= zbuf[pix])
        pix, k = pix[win], k[win]
        lam = np.empty((len(win), 3), np.float32 if weak_perspective else np.float64)
        lam[:, 0], lam[:, 1], lam[:, 2] = l0[win], l1[win], l2[win]
        if not weak_perspective:  # perspective-correct weights
            lam[:, 0] *= zc[0][k]
            lam[:, 1] *= zc[1][k]
            lam[:, 2] *= zc[2][k]
            lam /= lam.sum(axis=1, keepdims=True)
            lam = lam.astype(np.float32)
        tri[pix] = k if tri_ids is None else tri_ids[k]
        scatter_rows(bary, pix, lam)
    return Raster(triangle=tri.reshape(h, w), bary=bary.reshape(h, w, 3), depth=zbuf.reshape(h, w))


def _sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear texture colours (N, C) at (N, 2) uv (cv2.remap; maps kept under its 32767 limit)."""
    th, tw = texture.shape[:2]
    n = len(uv)
    cols = 1024
    rows = -(-n // cols)
    mx = np.zeros(rows * cols, dtype=np.float32)
    my = np.zeros(rows * cols, dtype=np.float32)
    mx[:n] = uv[:, 0] * tw - 0.5
    my[:n] = uv[:, 1] * th - 0.5
    out = cv2.remap(texture, mx.reshape(rows, cols), my.reshape(rows, cols), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(rows * cols, -1)[:n]


def render_mesh(vertices, faces, uv, texture, *, rotation=None, translation=None, focal: float, size,
                background=None, weak_perspective: bool = False):
    """Render a textured mesh: returns (image (H, W, 3) float32, mask (H, W) bool).

    ``uv`` (V, 2) per-vertex texture coordinates; ``texture`` (Ht, Wt, 3) float32 in [0, 1];
    ``size`` (W, H); ``background`` None (black), a colour (3,) or an (H, W, 3) image.
    """
    tex = np.asarray(texture)
    if tex.ndim != 3 or tex.shape[2] != 3 or tex.size == 0:
        raise BadInputError(f"texture must be an (H, W, 3) image, got shape {tex.shape}")
    tex = tex.astype(np.float32, copy=False)
    uv = np.asarray(uv, dtype=np.float64)
    nv = len(np.asarray(vertices))
    if uv.shape != (nv, 2):
        raise BadInputError(f"uv must be (V, 2) = ({nv}, 2), got {uv.shape}")
    w, h = _size(size)
    ras = rasterize(vertices, faces, rotation=rotation, translation=translation, focal=focal, size=size,
                    weak_perspective=weak_perspective)
    if background is None:
        image = np.zeros((h, w, 3), dtype=np.float32)
    else:
        bg = np.asarray(background, dtype=np.float32)
        if bg.shape == (3,):
            image = np.broadcast_to(bg, (h, w, 3)).copy()
        elif bg.shape == (h, w, 3):
            image = bg.copy()
        else:
            raise BadInputError(f"background must be a colour (3,) or an image {(h, w, 3)}, got {bg.shape}")
    mask = ras.triangle >= 0
    flat = np.flatnonzero(mask)
    if flat.size:
        f = np.asarray(faces, dtype=np.int64)
        t = ras.triangle.ravel()[flat]
        lam = ras.bary.reshape(-1, 3)[flat].astype(np.float64)
        corner_uv = uv[f[t]]  # (N, 3, 2)
        puv = np.einsum("nk,nkc->nc", lam, corner_uv)
        image.reshape(-1, 3)[flat] = _sample_texture(tex, puv)
    return image, mask


def vertex_normals(vertices, faces) -> np.ndarray:
    """Unit normals (V, 3) of a triangle mesh: the area-weighted sum of the adjacent faces'
    normals (cross product of the edges in the faces' winding order); 0 for unused vertices."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for c in range(3):  # bincount: a scatter-add much faster than np.add.at
        n[:, c] = sum(np.bincount(f[:, k], weights=fn[:, c], minlength=len(v)) for k in range(3))
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)


def interpolate_attributes(raster: Raster, faces, values) -> np.ndarray:
    """Per-pixel barycentric interpolation (H, W, C) of per-vertex ``values`` (V, C); 0 off the mesh."""
    f = np.asarray(faces, np.int64)
    vals = np.asarray(values, np.float32)
    h, w = raster.triangle.shape
    out = np.zeros((h * w, vals.shape[1]), np.float32)
    flat = np.flatnonzero(raster.triangle.ravel() >= 0)
    if flat.size:
        t = raster.triangle.ravel()[flat]
        lam = raster.bary.reshape(-1, 3)[flat]
        out[flat] = np.einsum("nk,nkc->nc", lam, vals[f[t]])
    return out.reshape(h, w, -1)


@dataclass(frozen=True, eq=False)
class Layers:
    """What :func:`render_layers` returns for an (H, W) image: image (H, W, 3) float32 (0 off the
    mesh), coverage (H, W) float32 in [0, 1] (fraction of sub-pixel samples on the mesh),
    normals (H, W, 3) float32 unit camera-space normals (0 off the mesh), box (y0, y1, x0, x1)
    the rows/columns that were rendered (everything outside is empty)."""

    image: np.ndarray
    coverage: np.ndarray
    normals: np.ndarray | None
    box: tuple[int, int, int, int]


def render_layers(vertices, faces, uv, texture, *, rotation, translation, size, supersample: int = 2,
                  normals: bool | np.ndarray = True, prefilter: bool = True) -> Layers:
    """Anti-aliased weak-perspective rendering of a textured mesh (the puppet's camera):
    pixel = rotation @ X + translation (x, y; z orders depth, smaller is nearer).

    Rasterized at ``supersample`` x the resolution inside the projected bounding box only and
    averaged down (box filter): edges get fractional coverage instead of stair steps. The
    texture is low-passed to the sample spacing first when it is minified (``prefilter``; a
    one-level mip map), so fine texture lines (lips, eyelids) do not alias either.
    ``normals``: True (per-vertex normals of the mesh, :func:`vertex_normals`), given
    per-vertex model-space normals (V, 3), or False (none).
    """
    w, h = _size(size)
    ss = max(1, int(supersample))
    v = np.asarray(vertices, np.float64)
    A = np.asarray(rotation, np.float64).reshape(3, 3)
    t = np.asarray(translation, np.float64).reshape(3)
    xy = v @ A[:2].T
    px, py = xy[:, 0] + t[0], xy[:, 1] + t[1]  # (per column: see _project)
    ok = np.isfinite(px) & np.isfinite(py)
    empty = Layers(np.zeros((h, w, 3), np.float32), np.zeros((h, w), np.float32),
                   None if normals is False else np.zeros((h, w, 3), np.float32), (0, 0, 0, 0))
    if not ok.any():
        return empty
    if not ok.all():
        px, py = px[ok], py[ok]
    lo = np.floor([px.min(), py.min()]).astype(int) - 1
    hi = np.ceil([px.max(), py.max()]).astype(int) + 2
    x0, y0 = max(0, lo[0]), max(0, lo[1])
    x1, y1 = min(w, hi[0]), min(h, hi[1])
    if x1 <= x0 or y1 <= y0:
        return empty
    bw, bh = x1 - x0, y1 - y0
    # sample (j, i) of the fine grid sits at box pixel ((j + 0.5) / ss - 0.5, ...)
    As = A * ss
    ts = np.r_[(t[:2] - [x0, y0] + 0.5) * ss - 0.5, t[2]]
    far = 1e6 + abs(float(ts[2]))  # camera far in front: every depth positive, projection scale exactly 1
    c = np.array([(bw * ss - 1) / 2.0, (bh * ss - 1) / 2.0])
    ras = rasterize(v, faces, rotation=As, translation=np.r_[ts[:2] - c, ts[2] + far], focal=ts[2] + far,
                    size=(bw * ss, bh * ss), weak_perspective=True)
    tex = np.asarray(texture, np.float32)
    if tex.ndim != 3 or tex.shape[2] != 3:
        raise BadInputError(f"texture must be an (H, W, 3) image, got shape {tex.shape}")
    uvv = np.asarray(uv, np.float64)
    if prefilter:
        # texels per fine sample along the texture's x axis (the canonical frame's pixels)
        texel_px = tex.shape[1] * float(np.ptp(uvv[:, 0]) or 1.0) / max(float(np.ptp(px)) * ss, 1e-6)
        if texel_px > 1.0:
            tex = cv2.GaussianBlur(tex, (0, 0), 0.5 * math.sqrt(texel_px ** 2 - 1.0))
    mask = ras.triangle >= 0
    img = np.zeros((bh * ss, bw * ss, 3), np.float32)
    flat = np.flatnonzero(mask)
    f = np.asarray(faces, np.int64)
    if flat.size:
        # row gathers by np.take (fancy indexing of short rows is several times slower)
        tri = ras.triangle.ravel()[flat]
        lam = ras.bary.reshape(-1, 3).take(flat, axis=0).astype(np.float64)
        puv = np.einsum("nk,nkc->nc", lam, uvv.take(f.take(tri, axis=0), axis=0))
        scatter_rows(img.reshape(-1, 3), flat, _sample_texture(tex, puv))
    cov = mask.astype(np.float32)
    nrm = None
    if normals is not False:
        vn = (vertex_normals(v, f) if normals is True else np.asarray(normals, np.float64)) @ A.T
        nn = np.linalg.norm(vn, axis=1, keepdims=True)
        vn = np.divide(vn, nn, out=np.zeros_like(vn), where=nn > 0)
        nrm = interpolate_attributes(ras, f, vn)
    if ss > 1:
        down = (lambda a: cv2.resize(a, (bw, bh), interpolation=cv2.INTER_AREA))
        img, cov = down(img), down(cov)
        nrm = down(nrm) if nrm is not None else None
    # colours are the average over the covered samples (premultiplied -> straight)
    straight, covered = np.zeros_like(img), cov > 1e-6
    for ch in range(3):  # one channel at a time: numpy broadcasts over a length-3 axis slowly
        np.divide(img[..., ch], cov, out=straight[..., ch], where=covered)
    img = straight
    if nrm is not None:
        nn = np.linalg.norm(nrm, axis=2, keepdims=True)
        nrm = np.divide(nrm, nn, out=np.zeros_like(nrm), where=nn > 1e-6)
    out_img = np.zeros((h, w, 3), np.float32)
    out_cov = np.zeros((h, w), np.float32)
    out_img[y0:y1, x0:x1], out_cov[y0:y1, x0:x1] = img, cov
    out_n = None
    if nrm is not None:
        out_n = np.zeros((h, w, 3), np.float32)
        out_n[y0:y1, x0:x1] = nrm
    return Layers(out_img, out_cov, out_n, (y0, y1, x0, x1))
