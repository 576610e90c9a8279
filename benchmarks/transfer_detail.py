"""How should FaceTex put the style's skin texture at the output's own resolution?

    python benchmarks/transfer_detail.py --data DIR [--pairs 4] [--variants a,b,...] [--out DIR]

Runs FaceTex (default preset) on content/style pairs of different people from a folder of
``NNN_neutral.jpg`` portraits (default $FACETEX_DATA/frl-london) in several variants and
prints one table (means over the pairs, per-pair values in ``--out``/results.json):

- ``cnn``: the optimisation at the default working size (384 px), no detail stage (the same
  run as ``cnn+detail``, its output before the detail stage);
- ``cnn+detail``: the same plus the native-resolution detail stage (the default);
- ``detail``: the detail stage alone (no optimisation);
- ``native``: the optimisation with its finest level at the face crop's native size;
- ``swag``: ``cnn`` with SWAG's channel softmax on the texture features;
- ``swag+detail``: both.

Columns: S gain = S(xt,xs) − S(xc,xs), detail ratio = detail(output)/detail(aligned style),
E(xt,xc), identity distance to the content, seconds of the run (load-dependent). Writes zoom
sheets per pair. Resumable: results.json in --out is reused.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

import facetex
from facetex.bench._common import list_portraits, select_pairs
from facetex.bench._zoom import zoom_sheet
from facetex.geometry.style_align import align_style_to_content
from facetex.io import write_image
from facetex.metrics import transfer_metrics
from facetex.transfer import face_crop_box, transfer_with_info

# variant -> (run options, which image of the run): one optimisation gives both the
# optimiser's own output (its pasted change, before the detail stage) and the final output
RUNS = {
    "default": {},
    "detail": {"iters": (0, 0, 0)},
    "swag": {"feature_transform": "softmax"},
    "native": {"detail": False, "size": "native"},
}
VARIANTS = {
    "cnn": ("default", "optimised"),
    "cnn+detail": ("default", "output"),
    "detail": ("detail", "output"),
    "swag": ("swag", "optimised"),
    "swag+detail": ("swag", "output"),
    "native": ("native", "output"),
}
KEYS = ("S_style_gain", "detail_ratio", "E_content", "identity_content", "seconds")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    env = os.environ.get("FACETEX_DATA")
    ap.add_argument("--data", type=Path, default=Path(env) / "frl-london" if env else None, required=env is None)
    ap.add_argument("--pairs", type=int, default=4)
    ap.add_argument("--seed", type=int, default=1, help="pair selection seed (default 1: not the bench's pairs)")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--out", type=Path, default=Path("benchmarks/out/transfer_detail"))
    ap.add_argument("--native-pairs", type=int, default=None, help="run the slow native variant on the first N pairs only")
    a = ap.parse_args()
    names = [v for v in a.variants.split(",") if v]
    portraits = list_portraits(a.data)
    pairs = select_pairs(list(portraits), a.pairs, seed=a.seed)
    a.out.mkdir(parents=True, exist_ok=True)
    results: dict = {}
    rpath = a.out / "results.json"
    if rpath.is_file():
        results = json.loads(rpath.read_text())
    for c, s in pairs:
        content, style = facetex.read_image(portraits[c]), facetex.read_image(portraits[s])
        pc = facetex.detect_face(content).points68
        ps = facetex.detect_face(style).points68
        aligned = align_style_to_content(style, content, style_points=ps, content_points=pc, refine=None,
                                         interpolation="lanczos").image
        cols = [("content", content), ("aligned style", aligned)]
        runs = {VARIANTS[v][0] for v in names}
        if a.native_pairs is not None and pairs.index((c, s)) >= a.native_pairs:
            runs.discard("native")
        for run in sorted(runs):
            todo = [v for v in names if VARIANTS[v][0] == run]
            if all(f"{c}__{s}__{v}" in results and (a.out / f"{c}__{s}__{v}.png").is_file() for v in todo):
                continue
            opts = dict(RUNS[run])
            if opts.get("size") == "native":
                box = face_crop_box(pc, content.shape)
                opts["size"] = int(max(box[2] - box[0], box[3] - box[1]))
            t0 = time.perf_counter()
            out, info = transfer_with_info(content, style, content_points=pc, style_points=ps, **opts)
            sec = time.perf_counter() - t0
            x0, y0, x1, y1 = info["region_box"]
            optimised = content.copy()
            optimised[y0:y1, x0:x1] = info["images"]["optimised_region"]
            for v in todo:
                img = out if VARIANTS[v][1] == "output" else optimised
                img = np.round(np.clip(img, 0, 1) * 255) / 255.0
                write_image(a.out / f"{c}__{s}__{v}.png", img, overwrite=True)
                m = transfer_metrics(img, content, style, points=(None, pc, ps), aligned_style=aligned)
                results[f"{c}__{s}__{v}"] = {k: float(m[k]) for k in KEYS[:-1]} | {"seconds": sec}
            rpath.write_text(json.dumps(results, indent=1))
        for v in names:
            if (a.out / f"{c}__{s}__{v}.png").is_file():
                cols.append((v, facetex.read_image(a.out / f"{c}__{s}__{v}.png")))
        write_image(a.out / f"zoom_{c}__{s}.png", zoom_sheet(cols, pc, title=f"{c} <- {s}"), overwrite=True)
    print(f"{len(pairs)} pairs: {', '.join(f'{c}<-{s}' for c, s in pairs)}")
    print(f"| variant | {' | '.join(KEYS)} |")
    print("|---" * (len(KEYS) + 1) + "|")
    for v in names:
        rows = [results[f"{c}__{s}__{v}"] for c, s in pairs if f"{c}__{s}__{v}" in results]
        vals = [np.mean([r[k] for r in rows]) for k in KEYS]
        print(f"| {v} | " + " | ".join(f"{x:+.3f}" if k == "S_style_gain" else f"{x:.2f}"
                                      for k, x in zip(KEYS, vals)) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
