"""Style-to-content alignment on FRL London neutral pairs of different people (1000 px).

For each pair (style = person 2i, content = person 2i+1) and each morph x refinement:
re-detect the 68 landmarks on the aligned style and report their mean distance (px) to the
content's (all points, and without the brows, which hair often hides), the normalised
cross-correlation of gradient magnitudes inside the content face (contour alignment), and
the morph / dense-refinement times. Saves style | content | aligned | 50/50 blend strips
for the first pairs under benchmarks/out/geometry/.

    python benchmarks/geometry_align.py [--data DATA/frl-london] [--pairs 10]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from facetex.geometry.masks import face_mask
from facetex.geometry.style_align import align_style_to_content
from facetex.geometry.morph import piecewise_affine_map, remap
from facetex.landmarks import detect_face

CONFIGS = [
    ("beier-neely", None),
    ("beier-neely", "optical-flow"),
    ("beier-neely", "sift-flow"),
    ("piecewise-affine", None),
    ("piecewise-affine", "optical-flow"),
    ("piecewise-affine", "sift-flow"),
]
NO_BROWS = np.array([i for i in range(68) if not 17 <= i <= 26])


def load(path: Path) -> np.ndarray:
    img = cv2.imread(str(path))
    if img is None:
        raise SystemExit(f"cannot read {path}")
    return img[..., ::-1].astype(np.float32) / 255.0


def grad_ncc(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    def gm(x):
        g = cv2.cvtColor(x, cv2.COLOR_RGB2GRAY)
        g = cv2.GaussianBlur(g, (0, 0), 1.5)
        return np.hypot(cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1))

    ga, gb = gm(a), gm(b)
    w = mask / mask.sum()
    ga, gb = ga - (w * ga).sum(), gb - (w * gb).sum()
    return float((w * ga * gb).sum() / np.sqrt((w * ga * ga).sum() * (w * gb * gb).sum()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", help="data root holding frl-london/ or the folder itself (default $FACETEX_DATA)")
    ap.add_argument("--pairs", type=int, default=10)
    ap.add_argument("--save", type=int, default=3, help="pairs to save images for")
    ap.add_argument("--out", default=str(Path(__file__).parent / "out" / "geometry"))
    args = ap.parse_args()
    from facetex.bench._common import data_folder, data_root  # --data or $FACETEX_DATA, never a machine path
    args.data = str(data_folder(data_root(args.data), 'frl-london'))
    files = sorted(Path(args.data).glob("*_neutral.jpg"))
    if len(files) < 2 * args.pairs:
        raise SystemExit(f"need {2 * args.pairs} neutral images in {args.data}, found {len(files)}")
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)

    rows = {c: [] for c in CONFIGS}
    failures: dict = {}
    pa_times, sk_times = [], []
    for i in range(args.pairs):
        fs, fc = files[2 * i], files[2 * i + 1]
        style, content = load(fs), load(fc)
        t0 = time.perf_counter()
        sp, cp = detect_face(style).points68, detect_face(content).points68
        t_lm = time.perf_counter() - t0
        fmask = face_mask(cp, content.shape[:2])
        raw = np.linalg.norm(sp - cp, axis=1).mean()
        print(f"pair {i}: style {fs.name} -> content {fc.name}  (raw landmark distance {raw:.1f} px, detection {t_lm:.2f} s)", flush=True)
        strips = []
        for method, refine in CONFIGS:
            try:
                r = align_style_to_content(style, content, style_points=sp, content_points=cp, method=method, refine=refine)
            except Exception as e:  # report and continue with the other configurations
                failures[(method, refine)] = f"{type(e).__name__}: {str(e).splitlines()[0][:80]}"
                continue
            rp = detect_face(r.image).points68
            err = np.linalg.norm(rp - cp, axis=1)
            rows[(method, refine)].append(
                dict(all=err.mean(), nobrow=err[NO_BROWS].mean(), ncc=grad_ncc(content, r.image, fmask),
                     pin=np.linalg.norm(r.points - cp, axis=1).max(), morph=r.timings["morph"], refine=r.timings["refine"])
            )
            if i < args.save and method == "beier-neely":
                strips.append((refine, r.image))
        if i < args.save and strips:
            for refine, img in strips:
                tile = np.hstack([style, content, img, 0.5 * img + 0.5 * content])
                name = out_dir / f"pair{i}_{fs.stem}_to_{fc.stem}_bn_{refine or 'none'}.jpg"
                cv2.imwrite(str(name), (np.clip(tile, 0, 1)[..., ::-1] * 255 + 0.5).astype(np.uint8)[::2, ::2])
        if i < 2:  # piecewise affine: ours vs scikit-image
            from skimage.transform import PiecewiseAffineTransform, warp

            t0 = time.perf_counter()
            remap(style, piecewise_affine_map(sp, cp, content.shape[:2]))
            pa_times.append(time.perf_counter() - t0)
            from facetex.geometry.morph import morph_points

            t0 = time.perf_counter()
            tf = PiecewiseAffineTransform.from_estimate(morph_points(cp, content.shape[:2]), morph_points(sp, style.shape[:2]))
            warp(style, tf, output_shape=content.shape[:2], order=1)
            sk_times.append(time.perf_counter() - t0)

    print()
    print("| morph | refine | lm err all (px) | median | no brows | grad NCC | max pin err | morph s | refine s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for (method, refine), rs in rows.items():
        if not rs:
            print(f"| {method} | {refine} | failed: {failures.get((method, refine), '?')} |||||||")
            continue
        a = {k: np.array([r[k] for r in rs]) for k in rs[0]}
        print(
            f"| {method} | {refine} | {a['all'].mean():.2f} | {np.median(a['all']):.2f} | {a['nobrow'].mean():.2f} | "
            f"{a['ncc'].mean():.3f} | {a['pin'].max():.2f} | {a['morph'].mean():.2f} | {a['refine'].mean():.2f} |"
        )
    if pa_times:
        print(f"\npiecewise affine warp, 1000 px: ours {np.mean(pa_times):.2f} s, scikit-image PiecewiseAffineTransform {np.mean(sk_times):.2f} s")
    print(f"images: {out_dir}")


if __name__ == "__main__":
    main()
