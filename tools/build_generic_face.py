"""Build ``facetex/data/generic_face.npz``, the generic 3D face used for frontalization.

Usage: python tools/build_generic_face.py [--data /work/shared/data/frl-london] [--out facetex/data/generic_face.npz]

Recipe (every step is a library call except the symmetrisation bookkeeping):

1. On every frontal ``*_neutral.jpg`` of the Face Research Lab London set
   (DeBruine & Jones 2017, CC BY 4.0; 60 people) detect the 68 dlib points
   (``facetex.landmarks.detect_face``) and run MediaPipe's 468-point face mesh
   (``facetex.landmarks.face_mesh468``: x, y, z in image pixels).
2. Generalised Procrustes analysis of the 60 meshes (similarity transforms,
   rotations by ``scipy.spatial.transform.Rotation.align_vectors``); the mean is
   put back in the average camera orientation of the (frontal) photos.
3. Triangulate: Delaunay on the frontal (x, y) of the mean mesh (MediaPipe's own
   tessellation is not shipped by any installed package), dropping the slivers
   Delaunay adds along the concave parts of the face outline (circumradius test).
4. Lift each photo's 68 dlib points onto its own mesh (barycentric z of the
   triangle under the point, nearest triangle for points outside the mesh), move
   them with that photo's Procrustes transform and average.
5. Make the model left-right symmetric (mirror correspondences found by
   assignment) with the symmetry plane at x = 0, scale it to millimetres
   (63 mm between the eye centres, the adult mean interpupillary distance) and
   put the origin midway between the eye centres.

Model axes follow the OpenCV camera: x to the image right (the subject's left),
y down, z away from the camera (the nose tip has the smallest z).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import Delaunay
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from facetex.geometry._generic_face import (  # noqa: E402
    CANONICAL_SIZE,
    EYE_DISTANCE_MM,
    FLIP68,
    barycentric_lift,
    canonical_depth_from_mesh,
    canonical_frame,
)
from facetex.landmarks import detect_face, face_mesh468  # noqa: E402

#: Delaunay triangles whose circumradius exceeds this multiple of the median are slivers.
SLIVER_RADIUS_FACTOR = 3.0


def _similarity_normalise(x: np.ndarray):
    c = x.mean(axis=0)
    s = np.sqrt(((x - c) ** 2).sum(axis=1).mean())
    return (x - c) / s, c, s


def generalised_procrustes(meshes: np.ndarray, iters: int = 20):
    """Mean shape and per-shape (centre, scale, rotation) so that rot.apply((m - c) / s) ~ mean."""
    norm = [_similarity_normalise(m) for m in meshes]
    mean = norm[0][0]
    rots = [Rotation.identity()] * len(meshes)
    for _ in range(iters):
        rots = [Rotation.align_vectors(mean, x)[0] for x, _, _ in norm]
        new = np.mean([r.apply(x) for r, (x, _, _) in zip(rots, norm)], axis=0)
        new = _similarity_normalise(new)[0]
        done = np.abs(new - mean).max() < 1e-9
        mean = new
        if done:
            break
    rots = [Rotation.align_vectors(mean, x)[0] for x, _, _ in norm]
    # undo the arbitrary orientation of the first shape: the average camera view
    cam_mean = np.mean([x for x, _, _ in norm], axis=0)
    back = Rotation.align_vectors(cam_mean, mean)[0]
    mean = back.apply(mean)
    rots = [back * r for r in rots]
    return mean, [(c, s, r) for (_, c, s), r in zip(norm, rots)]


def _cross2(p, q):
    return p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]


def delaunay_face(xy: np.ndarray) -> np.ndarray:
    tri = Delaunay(xy).simplices
    a, b, c = xy[tri[:, 0]], xy[tri[:, 1]], xy[tri[:, 2]]
    la, lb, lc = (np.linalg.norm(b - c, axis=1), np.linalg.norm(c - a, axis=1), np.linalg.norm(a - b, axis=1))
    area = 0.5 * np.abs(_cross2(b - a, c - a))
    radius = la * lb * lc / np.maximum(4 * area, 1e-12)
    keep = radius < SLIVER_RADIUS_FACTOR * np.median(radius)
    tri = tri[keep]
    # counter-clockwise in (x right, y down) image coordinates, i.e. positive cross product
    a, b, c = xy[tri[:, 0]], xy[tri[:, 1]], xy[tri[:, 2]]
    flip = _cross2(b - a, c - a) < 0
    tri[flip] = tri[flip][:, [0, 2, 1]]
    return tri.astype(np.int32)


def mirror_permutation(v: np.ndarray) -> np.ndarray:
    """perm with v[perm] * (-1, 1, 1) ~ v for a shape roughly symmetric about x = 0."""
    m = v * np.array([-1.0, 1.0, 1.0])
    cost = ((m[:, None, :] - v[None, :, :]) ** 2).sum(-1)
    rows, cols = linear_sum_assignment(cost)
    perm = np.empty(len(v), dtype=np.intp)
    perm[cols] = rows
    return perm


def symmetric_frame(mean: np.ndarray):
    """Rotation + centre that put the symmetry plane of ``mean`` at x = 0 (roll and yaw removed)."""
    v = mean - mean.mean(axis=0)
    for _ in range(3):
        perm = mirror_permutation(v)
        mid = (v + v[perm]) / 2  # on the symmetry plane
        d = v - v[perm]  # across it
        d = d[np.linalg.norm(d, axis=1) > 1e-3 * np.abs(v).max()]
        d *= np.sign(d[:, 0:1])
        normal = d.mean(axis=0)
        normal /= np.linalg.norm(normal)
        r = Rotation.align_vectors([[1.0, 0.0, 0.0]], [normal])[0]
        v = r.apply(v - mid.mean(axis=0))
    return v, mirror_permutation(v)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="/work/shared/data/frl-london")
    ap.add_argument("--out", default=str(ROOT / "facetex" / "data" / "generic_face.npz"))
    args = ap.parse_args(argv)

    files = sorted(Path(args.data).glob("*_neutral.jpg"))
    if not files:
        print(f"no *_neutral.jpg in {args.data}", file=sys.stderr)
        return 2
    t0 = time.time()
    meshes, pts68, used = [], [], []
    for f in files:
        img = cv2.imread(str(f), cv2.IMREAD_COLOR)[..., ::-1]
        try:
            face = detect_face(img, upsample=0, source=f)
            mesh = face_mesh468(img, face, source=f)
        except Exception as e:  # a photo without a usable face is skipped, and said so
            print(f"skip {f.name}: {e}", file=sys.stderr)
            continue
        meshes.append(mesh)
        pts68.append(face.points68.copy())
        used.append(f.name)
    meshes = np.array(meshes)
    print(f"{len(used)} photos measured in {time.time() - t0:.1f} s")

    # 2. GPA of the meshes
    mean, xforms = generalised_procrustes(meshes)
    # 3. triangulation of the mean's frontal view
    tri = delaunay_face(mean[:, :2])
    # 4. 68 dlib points lifted onto each photo's mesh, moved into the mean frame
    lifted = []
    for mesh, p, (c, s, r) in zip(meshes, pts68, xforms):
        p3 = barycentric_lift(mesh, tri, p)
        lifted.append(r.apply((p3 - c) / s))
    lifted = np.array(lifted)
    p68 = lifted.mean(axis=0)
    p68_spread = lifted.std(axis=0)

    # 5. symmetric, metric, eye-centred frame
    centre = mean.mean(axis=0)
    sym, perm = symmetric_frame(mean)
    r = Rotation.align_vectors(sym, mean - centre)[0]
    shift = (sym - r.apply(mean - centre)).mean(axis=0)
    p68 = r.apply(p68 - centre) + shift
    verts = (sym + sym[perm] * np.array([-1.0, 1.0, 1.0])) / 2
    p68 = (p68 + p68[FLIP68] * np.array([-1.0, 1.0, 1.0])) / 2
    eye_r, eye_l = p68[36:42].mean(axis=0), p68[42:48].mean(axis=0)
    scale = EYE_DISTANCE_MM / np.linalg.norm(eye_l - eye_r)
    origin = (eye_r + eye_l) / 2
    verts = (verts - origin) * scale
    p68 = (p68 - origin) * scale
    p68_spread *= scale
    # inner points back onto the (symmetrised) surface; jaw points are silhouette points, keep z
    p68[17:, 2] = barycentric_lift(verts, tri, p68[17:, :2])[:, 2]
    z0 = (p68[36:42, 2].mean() + p68[42:48, 2].mean()) / 2  # origin back between the eye centres
    p68[:, 2] -= z0
    verts[:, 2] -= z0
    mid = np.abs(p68[:, 0]) < 1e-9
    p68[mid, 0] = 0.0

    depth, on_mesh = canonical_depth_from_mesh(verts, tri, canonical_frame(CANONICAL_SIZE))
    provenance = (
        "Generic 3D face of facetex (tools/build_generic_face.py). Mean of MediaPipe 468-point face meshes"
        f" of {len(used)} frontal neutral portraits of the Face Research Lab London Set (DeBruine & Jones 2017,"
        " doi:10.6084/m9.figshare.5047666.v5, CC BY 4.0), generalised-Procrustes aligned and averaged;"
        " Delaunay triangulation of the mean's frontal view; the 68 iBUG points are dlib's 2D landmarks on the"
        " same photos lifted onto each mesh (barycentric z) and averaged. Symmetrised about x = 0; units mm"
        f" ({EYE_DISTANCE_MM} mm between eye centres); axes x right, y down, z away from the camera; origin"
        " midway between the eye centres."
    )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        out,
        vertices=verts.astype(np.float32),
        triangles=tri.astype(np.int32),
        mirror=perm.astype(np.int16),
        points68_3d=p68.astype(np.float64),
        points68_3d_std=p68_spread.astype(np.float32),
        depth=np.where(on_mesh, depth, np.nan).astype(np.float32),
        provenance=np.array(provenance),
        photos=np.array(used),
    )
    print(f"wrote {out} ({out.stat().st_size / 1024:.0f} KB): {len(verts)} vertices, {len(tri)} triangles;"
          f" 68-point spread (mean std) {p68_spread.mean():.2f} mm; {time.time() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
