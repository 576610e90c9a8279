"""Single-core timings of the 3D puppet parts (Tom Hanks §4 and §6 "Runtime").

    python benchmarks/puppet_parts.py [--n-images 200] [--frames 20] [--renders 20]

Times, with one thread (OMP/MKL/OpenBLAS = 1, cv2.setNumThreads(1)):
  * reconstruct_average_shape on N synthetic frontalized photos (192 x 240): the generic
    face depth, deepened 1.2x, rendered under N random first-order SH lights;
  * DeformationTransfer per frame incl. Huber-ROF, driver = that mesh, puppet = the generic
    mesh stretched 1.15x wide, for a local expression (surface-following bumps at mouth and
    eyes: most vertices still) and a worst case (every vertex moves);
  * render_mesh per frame at 256 x 256, ~22k triangles, 20 degree yaw, pinhole camera;
  * render_layers (the puppet's anti-aliased rendering with normals) at 1x and 2x supersampling,
    and composite_face (colour statistics, Poisson blending, mouth interior) on a synthetic frame.
Prints wall-clock and CPU (process) time: the CPU time is what one free core would take
when the machine is shared.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from facetex.geometry._generic_face import canonical_surface  # noqa: E402
from facetex.geometry.frontalize import rotation_from_angles  # noqa: E402
from facetex.puppet.deform import DeformationTransfer  # noqa: E402
from facetex.puppet.mesh_io import depth_to_mesh  # noqa: E402
from facetex.puppet.render import render_layers, render_mesh  # noqa: E402
from facetex.puppet.shape import generic_depth_px, normals_from_depth, reconstruct_average_shape  # noqa: E402

cv2.setNumThreads(1)


def timed(fn, repeat):
    wall, cpu = [], []
    out = None
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return out, 1000 * float(np.median(wall)), 1000 * float(np.median(cpu))


def synthetic_collection(depth, n, seed=0):
    rng = np.random.default_rng(seed)
    h, w = depth.shape
    normals = normals_from_depth(np.nan_to_num(depth, nan=float(np.nanmean(depth))))
    yy, xx = np.mgrid[0:h, 0:w]
    albedo = 0.5 + 0.2 * np.sin(xx / 9.0) * np.cos(yy / 13.0)
    out = np.empty((n, h, w, 3), np.float32)
    for i in range(n):
        d = rng.normal(size=3)
        d[2] = -abs(d[2]) - 0.8
        d /= np.linalg.norm(d)
        img = albedo * (rng.uniform(0.3, 0.7) + normals @ (0.6 * d)) + rng.normal(scale=0.01, size=(h, w))
        out[i] = np.clip(img, 0, 1)[..., None]
    return out


def surface_following(depth, dx, dy):
    h, w = depth.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    z = np.nan_to_num(depth, nan=float(np.nanmean(depth))).astype(np.float32)
    z1 = cv2.remap(z, xx + dx.astype(np.float32), yy + dy.astype(np.float32), cv2.INTER_LINEAR,
                   borderMode=cv2.BORDER_REPLICATE)
    return np.stack([dx, dy, z1 - z], axis=-1).astype(np.float64)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n-images", type=int, default=200)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--renders", type=int, default=20)
    args = ap.parse_args(argv)
    rows = []

    w, h = 192, 240
    mask = canonical_surface((w, h)).on_mesh
    truth = 1.2 * generic_depth_px((w, h))
    images = synthetic_collection(truth, args.n_images)
    shape, wall, cpu = timed(lambda: reconstruct_average_shape(images, mask), 1)
    corr = np.corrcoef(shape.depth[mask], truth[mask])[0, 1]
    rows.append((f"reconstruct_average_shape, {args.n_images} photos {w}x{h}", wall, cpu,
                 f"depth corr {corr:.3f}, {int(mask.sum())} px"))

    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    driver = np.stack([xx, yy, shape.depth], axis=-1)
    wp = int(round(w * 1.15))
    pmask = cv2.resize(mask.astype(np.uint8), (wp, h), interpolation=cv2.INTER_NEAREST).astype(bool)
    pdepth = cv2.resize(np.nan_to_num(shape.depth).astype(np.float32), (wp, h), interpolation=cv2.INTER_LINEAR)
    pyy, pxx = np.mgrid[0:h, 0:wp].astype(np.float64)
    puppet = np.stack([pxx, pyy, pdepth], axis=-1)
    corr_map = np.stack([xx * (wp - 1) / (w - 1), yy], axis=-1)
    dt, wall, cpu = timed(lambda: DeformationTransfer(driver, puppet, corr_map, driver_mask=mask,
                                                      puppet_mask=pmask), 1)
    rows.append(("DeformationTransfer setup (KD-tree, inverse map)", wall, cpu, "once per driver/puppet pair"))

    def bump(cx, cy, s):
        return np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * s**2))

    local = surface_following(shape.depth, 1.5 * bump(96, 185, 18), 3.0 * bump(96, 185, 18)
                              + 2.0 * (bump(62, 96, 8) + bump(130, 96, 8)))
    rng = np.random.default_rng(1)
    every = surface_following(shape.depth, 1.0 + 0.3 * rng.standard_normal((h, w)),
                              2.0 + 0.3 * rng.standard_normal((h, w)))
    for name, delta in (("local expression", local), ("every vertex moves", every)):
        moving = float((np.linalg.norm(delta[mask], axis=1) > 0.5).mean())
        _, wall, cpu = timed(lambda: dt(delta), args.frames)
        rows.append((f"DeformationTransfer per frame, {name}", wall, cpu, f"{100 * moving:.0f}% move > 0.5 px"))
    from facetex.puppet.deform import huber_rof

    field = rng.standard_normal((h, w)).astype(np.float32)
    _, wall, cpu = timed(lambda: huber_rof(field, mask=mask), args.frames)
    rows.append(("  of which huber_rof (50 iterations)", wall, cpu, ""))

    small = canonical_surface((136, 170))
    v, f, uv = depth_to_mesh(generic_depth_px((136, 170)), small.on_mesh)
    v = v - [67.5, 84.5, float(np.mean(v[:, 2]))]
    tex = np.clip(images[0] * 1.2, 0, 1)
    rot = rotation_from_angles(yaw=20)
    (img, m), wall, cpu = timed(lambda: render_mesh(v, f, uv, tex, rotation=rot, translation=(0, 0, 400),
                                                    focal=560, size=(256, 256)), args.renders)
    rows.append((f"render_mesh 256x256, {len(f)} triangles", wall, cpu, f"{int(m.sum())} px covered"))
    # the puppet's anti-aliased layers (weak perspective, as the puppet is drawn) and its composite
    A = 0.9 * rot
    t = np.array([128.0, 128.0, 0.0])
    for ss in (1, 2):
        lay, wall, cpu = timed(lambda: render_layers(v, f, uv, tex, rotation=A, translation=t, size=(256, 256),
                                                     supersample=ss), args.renders)
        rows.append((f"render_layers 256x256, supersample {ss} (+ normals)", wall, cpu,
                     f"{lay.coverage.sum():.0f} px covered"))
    from facetex.puppet.composite import composite_face

    lay = render_layers(v, f, uv, tex, rotation=A, translation=t, size=(256, 256), supersample=1)
    frame = np.clip(np.full((256, 256, 3), (0.55, 0.4, 0.3), np.float32)
                    + 0.02 * rng.standard_normal((256, 256, 3)).astype(np.float32), 0, 1)
    ang = np.linspace(0, 2 * np.pi, 36, endpoint=False)
    oval = np.c_[128 + 55 * np.cos(ang), 128 + 70 * np.sin(ang)]
    p68 = np.tile([128.0, 128.0], (68, 1))
    p68[36], p68[45] = (98, 110), (158, 110)
    p68[60:68] = np.c_[128 + 18 * np.cos(np.linspace(np.pi, -np.pi, 8, endpoint=False)),
                       165 + 5 * np.sin(np.linspace(np.pi, -np.pi, 8, endpoint=False))]
    (_, alpha), wall, cpu = timed(lambda: composite_face(frame, lay.image, lay.coverage, lay.normals, driver_oval=oval,
                                                         driver_points68=p68, puppet_lips=p68[60:68] + [0, 2]),
                                  args.renders)
    rows.append(("composite_face 256x256 (colour, Poisson, mouth interior)", wall, cpu,
                 f"{(alpha > 0.5).sum()} px composited"))

    print(f"{'step':58s} {'wall ms':>9s} {'cpu ms':>9s}  note")
    for name, wall, cpu, note in rows:
        print(f"{name:58s} {wall:9.1f} {cpu:9.1f}  {note}")
    print(f"(load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")


if __name__ == "__main__":
    main()
