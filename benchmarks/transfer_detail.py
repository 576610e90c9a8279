"""How should FaceTex put the style's skin texture at the output's own resolution?

    python benchmarks/transfer_detail.py --data DIR [--pairs 4] [--variants a,b,...] [--out DIR]

Runs FaceTex (default preset) on content/style pairs of different people from a folder of
``NNN_neutral.jpg`` portraits (default $FACETEX_DATA/frl-london) in several variants and
prints one table (means over the pairs, per-pair values in ``--out``/results.json):

- ``cnn``: the optimisation at the default working size (384 px), no detail stage;
- ``cnn+detail``: the same plus the native-resolution detail stage (the default);
- ``detail``: the detail stage alone (no optimisation);
- ``native``: the optimisation with its finest level at the face crop's native size;
- ``swag``: ``cnn`` with SWAG's channel softmax on the texture features;
- ``swag+detail``: both.

Columns: S gain = S(xt,xs) − S(xc,xs), detail ratio = detail(output)/detail(aligned style),
E(xt,xc), identity distance to the content, seconds. Writes zoom sheets per pair.
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
from facetex.geometry.morph import align_style_to_content
from facetex.io import write_image
from facetex.metrics import transfer_metrics
from facetex.transfer import face_crop_box, transfer_with_info

VARIANTS = {
    "cnn": {"detail": False},
    "cnn+detail": {},
    "detail": {"iters": (0, 0, 0)},
    "native": {"detail": False, "size": "native"},
    "swag": {"detail": False, "feature_transform": "softmax"},
    "swag+detail": {"feature_transform": "softmax"},
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
        for v in names:
            key = f"{c}__{s}__{v}"
            img_path = a.out / f"{key}.png"
            opts = dict(VARIANTS[v])
            if opts.get("size") == "native":
                box = face_crop_box(pc, content.shape)
                opts["size"] = int(max(box[2] - box[0], box[3] - box[1]))
            if key not in results or not img_path.is_file():
                t0 = time.perf_counter()
                out, _ = transfer_with_info(content, style, content_points=pc, style_points=ps, **opts)
                sec = time.perf_counter() - t0
                out = np.round(np.clip(out, 0, 1) * 255) / 255.0
                write_image(img_path, out, overwrite=True)
                m = transfer_metrics(out, content, style, points=(None, pc, ps), aligned_style=aligned)
                results[key] = {k: float(m[k]) for k in KEYS[:-1]} | {"seconds": sec}
                rpath.write_text(json.dumps(results, indent=1))
            cols.append((v, facetex.read_image(img_path)))
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
