"""Benchmark of facetex.geometry.frontalize on a photo collection (default: LFW George_W_Bush).

    python benchmarks/geometry_frontalize.py [--data DATA/lfw/George_W_Bush] [--n 50]

Prints: ms per photo for landmark detection (dlib, timed separately), head pose, and
pose + frontalization; the spread of landmarks re-detected on the frontalized outputs
around the canonical positions (mean px in the 192 x 240 frame), next to the same
spread for a 2D similarity alignment baseline; and a yaw histogram. Saves a few
before/after strips under benchmarks/out/frontalize/ (not committed).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from facetex.errors import FacetexError  # noqa: E402
from facetex.geometry.frontalize import (  # noqa: E402
    CANONICAL_SIZE,
    canonical_points68,
    estimate_head_pose,
    frontalize,
)
from facetex.landmarks import detect_face  # noqa: E402

INNER = np.arange(17, 68)


def _read(path: Path) -> np.ndarray:
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise FacetexError("unreadable image", path=path)
    return (bgr[..., ::-1] / 255.0).astype(np.float32)


def _u8(a: np.ndarray) -> np.ndarray:
    a = np.clip(a, 0, 1)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    return (a * 255 + 0.5).astype(np.uint8)[..., ::-1]


def _dots(img: np.ndarray, pts, colour) -> np.ndarray:
    img = img.copy()
    for x, y in pts:
        cv2.circle(img, (int(round(x)), int(round(y))), 1, colour, -1, lineType=cv2.LINE_AA)
    return img


def _dist(a, b, idx=slice(None)) -> float:
    return float(np.linalg.norm(np.asarray(a)[idx] - np.asarray(b)[idx], axis=1).mean())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", help="data root holding lfw/George_W_Bush/ or the folder itself (default $FACETEX_DATA)")
    ap.add_argument("--n", type=int, default=50, help="number of photos (sorted by name)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out" / "frontalize"))
    ap.add_argument("--save", type=int, default=8, help="before/after strips to save")
    args = ap.parse_args(argv)
    from facetex.bench._common import data_folder, data_root  # --data or $FACETEX_DATA, never a machine path
    args.data = str(data_folder(data_root(args.data), 'lfw/George_W_Bush'))

    files = sorted(p for p in Path(args.data).iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png"))[: args.n]
    if not files:
        print(f"no images in {args.data}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    canon = canonical_points68()
    W, H = CANONICAL_SIZE

    # warm-up: load models and build the canonical surface outside the timings
    img0 = _read(files[0])
    f0 = detect_face(img0)
    frontalize(img0, f0.points68)

    t_det, t_pose, t_front, yaws, rms = [], [], [], [], []
    d_front, d_front_in, d_sim, d_sim_in, d_pc, d_redet_pc = [], [], [], [], [], []
    fails_det = fails_redet = fails_sim = 0
    saved = 0
    for path in files:
        img = _read(path)
        t = time.perf_counter()
        try:
            face = detect_face(img, source=path)
        except FacetexError:
            fails_det += 1
            continue
        t_det.append(time.perf_counter() - t)
        p = face.points68
        t = time.perf_counter()
        pose = estimate_head_pose(p, img.shape)
        t_pose.append(time.perf_counter() - t)
        t = time.perf_counter()
        fr = frontalize(img, p)  # pose + back-projection + visibility + symmetry fill
        t_front.append(time.perf_counter() - t)
        yaws.append(pose.yaw)
        rms.append(pose.rms_px)
        d_pc.append(_dist(fr.points68, canon))
        try:
            again = detect_face(fr.image).points68
            d_front.append(_dist(again, canon))
            d_front_in.append(_dist(again, canon, INNER))
            d_redet_pc.append(_dist(again, fr.points68))
        except FacetexError:
            fails_redet += 1
        # baseline: 2D similarity of the inner landmarks onto the canonical ones
        a, _ = cv2.estimateAffinePartial2D(p[INNER].astype(np.float32), canon[INNER].astype(np.float32))
        sim = cv2.warpAffine(img, a, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        try:
            again = detect_face(sim).points68
            d_sim.append(_dist(again, canon))
            d_sim_in.append(_dist(again, canon, INNER))
        except FacetexError:
            fails_sim += 1
        if saved < args.save:
            plain = frontalize(img, p, symmetry_fill=False, pose=pose)
            scale = H / img.shape[0]
            before = cv2.resize(_dots(_u8(img), p, (0, 0, 255)), None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
            strip = np.concatenate(
                [
                    before,
                    _dots(_u8(plain.image), canon, (0, 255, 0)),
                    _u8(plain.visibility),
                    _dots(_u8(fr.image), fr.points68, (0, 0, 255)),
                ],
                axis=1,
            )
            cv2.putText(strip, f"yaw {pose.yaw:+.0f} pitch {pose.pitch:+.0f}", (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                        (255, 255, 255), 1, cv2.LINE_AA)
            cv2.imwrite(str(out / f"{path.stem}.jpg"), strip)
            saved += 1

    n = len(t_front)
    ms = lambda v: f"{1000 * np.mean(v):6.1f} (median {1000 * np.median(v):.1f})"  # noqa: E731
    print(f"photos: {len(files)} ({fails_det} without a detected face), frontalized: {n}, {args.data}")
    print(f"landmark detection (dlib, ms/photo)          : {ms(t_det)}")
    print(f"head pose only (ms/photo)                    : {ms(t_pose)}")
    print(f"pose + frontalization {W}x{H} (ms/photo)    : {ms(t_front)}")
    print(f"PnP reprojection RMS (px, photo)             : {np.mean(rms):.2f}")
    print("landmark spread vs canonical positions (mean px over 68 | 51 inner points, canonical frame):")
    print(f"  re-detected on frontalized outputs         : {np.mean(d_front):.2f} | {np.mean(d_front_in):.2f}"
          f"   ({fails_redet} not re-detected)")
    print(f"  re-detected after 2D similarity alignment  : {np.mean(d_sim):.2f} | {np.mean(d_sim_in):.2f}"
          f"   ({fails_sim} not re-detected)")
    print(f"  pose-corrected fiducials                   : {np.mean(d_pc):.2f}")
    print(f"  re-detected vs pose-corrected              : {np.mean(d_redet_pc):.2f}")
    hist, edges = np.histogram(yaws, bins=np.arange(-45, 50, 5))
    print(f"yaw (deg): mean {np.mean(yaws):+.1f}, |yaw| mean {np.mean(np.abs(yaws)):.1f}, min {np.min(yaws):+.1f},"
          f" max {np.max(yaws):+.1f}; outside [-45, 45]: {int(np.sum(np.abs(yaws) >= 45))}")
    for c, lo in zip(hist, edges[:-1]):
        if c:
            print(f"  [{lo:+4.0f}, {lo + 5:+4.0f}) {'#' * c} {c}")
    print(f"saved {saved} before/after strips (photo | frontal, no fill | visibility | frontal, filled) to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
