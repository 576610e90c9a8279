"""Depth-map meshes and Wavefront .obj export (viewable in Blender, MeshLab, any 3D viewer).

Mesh convention (as the generic face and :mod:`facetex.puppet.shape`): vertices in
OpenCV camera axes (x right, y down, z away from the camera); ``uv`` in [0, 1] with
u to the right and v DOWN the texture image, pixel edges at 0 and 1 (texel centre
of column j at (j + 0.5) / W). Faces are counter-clockwise seen from the camera in
a y-up view, which is what OBJ/OpenGL viewers treat as front-facing after
:func:`write_obj` turns the axes to y up, z towards the viewer.
"""

from __future__ import annotations

import io as _io
from pathlib import Path

import numpy as np

from ..errors import BadInputError, OutputError
from ..io import check_output_path, encode_image, write_files

__all__ = ["depth_to_mesh", "write_obj", "read_obj"]

#: OpenCV camera axes -> OBJ/OpenGL axes (x right, y up, z to the viewer): a rotation by pi about x.
_TO_GL = np.array([1.0, -1.0, -1.0])


def depth_to_mesh(depth, mask=None, *, step: int = 1):
    """Triangulate a depth map over ``mask`` on a regular grid of ``step`` px.

    Returns vertices (V, 3) float64 (x, y, depth) in pixels of the depth map, faces
    (F, 3) int64 (two triangles per grid cell with four corners in the mask, one per
    cell with three), uv (V, 2) float64 of each vertex in the depth map's image.
    """
    z = np.asarray(depth, dtype=np.float64)
    if z.ndim != 2:
        raise BadInputError(f"depth must be a 2-D map, got shape {z.shape}")
    m = np.isfinite(z) if mask is None else (np.asarray(mask, dtype=bool) & np.isfinite(z))
    if m.shape != z.shape:
        raise BadInputError(f"mask is {m.shape} but depth is {z.shape}")
    step = int(step)
    if step < 1:
        raise BadInputError(f"step must be a positive integer, got {step}")
    h, w = z.shape
    ys, xs = np.arange(0, h, step), np.arange(0, w, step)
    sub = m[np.ix_(ys, xs)]
    idx = -np.ones(sub.shape, dtype=np.int64)
    idx[sub] = np.arange(int(sub.sum()))
    gy, gx = np.nonzero(sub)
    px, py = xs[gx].astype(np.float64), ys[gy].astype(np.float64)
    vertices = np.stack([px, py, z[py.astype(int), px.astype(int)]], axis=1)
    uv = np.stack([(px + 0.5) / w, (py + 0.5) / h], axis=1)
    # cell corners a (top-left), b (top-right), c (bottom-left), d (bottom-right)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    ia, ib, ic, id_ = a >= 0, b >= 0, c >= 0, d >= 0
    full = ia & ib & ic & id_
    tris = [
        np.stack([a[full], c[full], b[full]], 1),
        np.stack([b[full], c[full], d[full]], 1),
    ]
    three = (ia.astype(int) + ib + ic + id_) == 3
    for missing, corners in ((~ia, (b, c, d)), (~ib, (a, c, d)), (~ic, (a, d, b)), (~id_, (a, c, b))):
        sel = three & missing
        tris.append(np.stack([k[sel] for k in corners], 1))
    faces = np.concatenate(tris, axis=0).astype(np.int64)
    return vertices, faces, uv


def _table(fmt: str, arr: np.ndarray) -> str:
    buf = _io.StringIO()
    np.savetxt(buf, arr, fmt=fmt)
    return buf.getvalue()


def write_obj(path, vertices, faces, uv=None, texture=None, *, overwrite: bool = True,
              to_gl_axes: bool = True, inputs=(), extra_files=None) -> Path:
    """Write a mesh as ``path`` (.obj), with ``<stem>.mtl`` and ``<stem>.png`` when ``texture``
    (H, W, 3) float [0, 1] is given (it needs ``uv``). The files are written together: all of
    them or none (:func:`facetex.io.write_files`; exclusive creates unless ``overwrite``);
    ``extra_files`` ({path: bytes}, e.g. a provenance sidecar) are committed with them.
    ``to_gl_axes`` turns OpenCV axes into the y-up axes viewers expect. Returns the .obj path.
    """
    path = Path(path)
    if path.suffix.lower() != ".obj":
        raise OutputError("mesh file name must end in .obj", path=path)
    check_output_path(path, overwrite=overwrite, inputs=inputs)
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise BadInputError(f"need vertices (V, 3) and faces (F, 3), got {v.shape} and {f.shape}", path=path)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise BadInputError("faces index vertices that do not exist", path=path)
    if uv is not None:
        uv = np.asarray(uv, dtype=np.float64)
        if uv.shape != (len(v), 2):
            raise BadInputError(f"uv must be (V, 2) = ({len(v)}, 2), got {uv.shape}", path=path)
    if texture is not None and uv is None:
        raise BadInputError("a texture needs uv coordinates", path=path)
    if to_gl_axes:
        v = v * _TO_GL
    header = [f"# facetex mesh: {len(v)} vertices, {len(f)} faces"]
    files = {}
    if texture is not None:
        mtl, png = path.with_suffix(".mtl"), path.with_suffix(".png")
        files[png] = encode_image(png, texture)
        files[mtl] = f"newmtl face\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nillum 1\nmap_Kd {png.name}\n"
        header += [f"mtllib {mtl.name}", "usemtl face"]
    parts = ["\n".join(header) + "\n", _table("v %.6f %.6f %.6f", v)]
    if uv is not None:
        # OBJ texture v runs up from the bottom of the image
        parts.append(_table("vt %.6f %.6f", np.stack([uv[:, 0], 1.0 - uv[:, 1]], 1)))
        parts.append(_table("f %d/%d %d/%d %d/%d", np.repeat(f + 1, 2, axis=1)))
    else:
        parts.append(_table("f %d %d %d", f + 1))
    files[path] = "".join(parts)
    files.update(extra_files or {})
    write_files(files, overwrite=overwrite, inputs=inputs)
    return path


def read_obj(path, *, from_gl_axes: bool = True):
    """Read (vertices, faces, uv or None) of a triangle .obj as written by :func:`write_obj`
    (faces index vertices; per-corner texture indices are assumed equal to vertex indices)."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise BadInputError(f"cannot read mesh file ({e.__class__.__name__}): check the path", path=path) from None
    v, vt, f = [], [], []
    for line in lines:
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "v":
            v.append([float(t) for t in tok[1:4]])
        elif tok[0] == "vt":
            vt.append([float(t) for t in tok[1:3]])
        elif tok[0] == "f":
            if len(tok) != 4:
                raise BadInputError("only triangle meshes are supported: triangulate the mesh first", path=path)
            f.append([int(t.split("/")[0]) - 1 for t in tok[1:]])
    vertices = np.array(v, dtype=np.float64).reshape(-1, 3)
    if from_gl_axes:
        vertices = vertices * _TO_GL
    faces = np.array(f, dtype=np.int64).reshape(-1, 3)
    uv = None
    if vt:
        t = np.array(vt, dtype=np.float64)
        uv = np.stack([t[:, 0], 1.0 - t[:, 1]], 1)
    return vertices, faces, uv
