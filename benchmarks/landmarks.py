"""Landmark accuracy and speed on Helen test photos with 300-W ground truth.

    python benchmarks/landmarks.py [--data DATA] [--detector hog|cnn]

NME = mean point-to-point distance of the 68 points / distance between the
ground truth's outer eye corners (36 and 45, 0-based). The .pts files are in
the 300-W convention, usually taken as 1-based; both readings (subtract 1 or
not) are reported. Per image, the detection that best overlaps the ground-truth
points' box is used; if none overlaps (IoU < 0.3) the search is repeated with
upsample 1 (and, with --cnn-fallback, with the CNN detector: "c" in the up
column). Times are per face: detection (all tries) and the 68-point
shape predictor separately, plus the MediaPipe mesh for reference.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from facetex.errors import FacetexError
from facetex.io import read_image
from facetex.landmarks import _as_uint8_rgb, _detect_rects, _model, _rect_box, _shape68, face_mesh468


def iou(a, b) -> float:
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    area = lambda r: max(0.0, r[2] - r[0]) * max(0.0, r[3] - r[1])  # noqa: E731
    return inter / max(area(a) + area(b) - inter, 1e-9)


def nme(points: np.ndarray, gt: np.ndarray) -> float:
    return float(np.linalg.norm(points - gt, axis=1).mean() / np.linalg.norm(gt[36] - gt[45]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", help="data root holding helen-300w/ or the folder itself (default $FACETEX_DATA)")
    ap.add_argument("--detector", choices=("hog", "cnn"), default="hog")
    ap.add_argument("--max-upsample", type=int, default=1)
    ap.add_argument("--cnn-fallback", action="store_true",
                    help="with --detector hog: try the CNN detector (upsample 0) on images HOG misses")
    args = ap.parse_args(argv)
    from facetex.bench._common import data_folder, data_root  # --data or $FACETEX_DATA, never a machine path
    args.data = str(data_folder(data_root(args.data), 'helen-300w'))

    jpgs = sorted(p for p in Path(args.data).glob("*.jpg") if p.with_suffix(".pts").is_file())
    if not jpgs:
        print(f"no .jpg + .pts pairs in {args.data}", file=sys.stderr)
        return 1
    for name in (args.detector, "shape68", "mesh") + (("cnn",) if args.cnn_fallback else ()):
        _model(name)  # load models outside the timings
    rows = []
    for jp in jpgs:
        img8 = _as_uint8_rgb(read_image(jp))
        gt1 = np.loadtxt(jp.with_suffix(".pts"), dtype=np.float64).reshape(-1, 2)
        assert gt1.shape == (68, 2), jp
        gt_box = (*gt1.min(0), *gt1.max(0))
        t0 = time.perf_counter()
        best, n_up = None, 0
        for n_up in range(args.max_upsample + 1):
            dets = _detect_rects(img8, n_up, args.detector)
            if dets:
                r = max(dets, key=lambda d: iou(_rect_box(d[0]), gt_box))[0]
                if iou(_rect_box(r), gt_box) >= 0.3:
                    best = r
                    break
        if best is None and args.cnn_fallback and args.detector == "hog":
            dets = _detect_rects(img8, 0, "cnn")
            if dets:
                r = max(dets, key=lambda d: iou(_rect_box(d[0]), gt_box))[0]
                best, n_up = (r, "c") if iou(_rect_box(r), gt_box) >= 0.3 else (None, n_up)
        t_det = time.perf_counter() - t0
        if best is None:
            rows.append(dict(name=jp.stem, found=False, t_det=t_det, size=img8.shape[:2]))
            continue
        t0 = time.perf_counter()
        p = _shape68(img8, best)
        t_lm = time.perf_counter() - t0
        t0 = time.perf_counter()
        try:
            face_mesh468(img8, p)
            t_mesh = time.perf_counter() - t0
        except FacetexError:
            t_mesh = float("nan")
        rows.append(dict(name=jp.stem, found=True, up=n_up, t_det=t_det, t_lm=t_lm, t_mesh=t_mesh,
                         nme1=nme(p, gt1 - 1.0), nme0=nme(p, gt1), size=img8.shape[:2]))

    ok = [r for r in rows if r["found"]]
    print(f"{'image':<16} {'size':>9} {'up':>2} {'NME(-1)':>8} {'NME(0)':>7} {'det ms':>7} {'lm ms':>6}")
    for r in rows:
        size = f"{r['size'][1]}x{r['size'][0]}"
        if r["found"]:
            print(f"{r['name']:<16} {size:>9} {r['up']:>2} {r['nme1']:8.4f} {r['nme0']:7.4f}"
                  f" {r['t_det'] * 1e3:7.1f} {r['t_lm'] * 1e3:6.2f}")
        else:
            print(f"{r['name']:<16} {size:>9}  - {'no face':>8}")
    print()
    n1, n0 = np.array([r["nme1"] for r in ok]), np.array([r["nme0"] for r in ok])
    print(f"| detector | faces found | NME mean (.pts - 1) | NME median (.pts - 1) | NME mean (.pts as is)"
          f" | NME > 0.1 | detection ms/face | 68 points ms/face | mesh468 ms/face |")
    print("|---|---|---|---|---|---|---|---|---|")
    label = f"dlib {args.detector}" + (" (+cnn fallback)" if args.cnn_fallback else "")
    print(f"| {label} | {len(ok)}/{len(rows)} | {n1.mean():.4f} | {np.median(n1):.4f} | {n0.mean():.4f}"
          f" | {(n1 > 0.1).sum()} | {np.mean([r['t_det'] for r in ok]) * 1e3:.1f}"
          f" | {np.mean([r['t_lm'] for r in ok]) * 1e3:.2f} | {np.nanmean([r['t_mesh'] for r in ok]) * 1e3:.2f} |")
    better = "subtracting 1 (1-based .pts)" if n1.mean() <= n0.mean() else "no offset (0-based .pts)"
    print(f"lower error with {better}; target NME <= 0.06: {'met' if min(n1.mean(), n0.mean()) <= 0.06 else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
