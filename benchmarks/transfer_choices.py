"""Measure the choices behind the transfer defaults (docs/texture-nets.md).

Studies (each a list of named configurations = method + TransferParams overrides):

- ``nets``      texture network and MRF layers, for the ``facetex`` and ``mrf`` methods;
- ``structure`` FaceRecognitionNet layers and weight of the structure loss (Eq. 3);
- ``weights``   the default preset of all three methods (paper claims of Table 1);
- ``verify``    the three methods' defaults (run with ``--size 384 --iters 100,100,100``);
- ``timing``    FaceTex at 384 and 512 px, 3 × 100 iterations (run with ``--threads 2`` when idle).

Every configuration runs on the same FRL London pairs of different people, resized to
500 px (the transfer works on a face crop), at ``--size`` with ``--iters`` unless the
configuration sets them. Results are cached per (configuration, pair) as JSON under
``benchmarks/out/choices/results`` (delete a file to re-run it); per study the script writes
``<study>.md`` (means over the pairs) and ``<study>_<pair>.png`` (face crops side by side).

    python benchmarks/transfer_choices.py nets [--only name1,name2] [--pairs 4]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np

from facetex.bench._common import image_grid
from facetex.io import read_image, to_uint8, write_image
from facetex.landmarks import detect_face
from facetex.metrics import transfer_metrics
from facetex.transfer import face_crop_box, preset, transfer_with_info

DATA = Path(__import__("os").environ.get("FACETEX_DATA", "FACETEX_DATA-not-set")) / "frl-london"  # data root: $FACETEX_DATA
OUT = Path(__file__).resolve().parent / "out" / "choices"
PAIRS = (("004", "005"), ("004", "012"), ("004", "020"), ("008", "033"))
INPUT_SIZE = 500
QUICK = {"size": 256, "iters": (40, 40, 40)}

MRF1 = {"mrf_weight": 1.0}  # the FaceTex texture weight when the nets and structure studies ran
STUDIES: dict[str, dict[str, tuple[str, dict]]] = {
    "nets": {
        **{f"{m}:effnet b2+b4": (m, {"texture_net": "effnet-lite0", "mrf_layers": ("block2", "block4"), **MRF1})
           for m in ("facetex", "mrf")},
        **{f"{m}:effnet b1+b4": (m, {"texture_net": "effnet-lite0", "mrf_layers": ("block1", "block4"), **MRF1})
           for m in ("facetex", "mrf")},
        **{f"{m}:effnet b4": (m, {"texture_net": "effnet-lite0", "mrf_layers": ("block4",), **MRF1})
           for m in ("facetex", "mrf")},
        **{f"{m}:face-resnet pool1+l2": (m, {"texture_net": "face-resnet", "mrf_layers": ("pool1", "level2"), **MRF1})
           for m in ("facetex", "mrf")},
        **{f"{m}:face-resnet l1+l2": (m, {"texture_net": "face-resnet", "mrf_layers": ("level1", "level2"), **MRF1})
           for m in ("facetex", "mrf")},
        **{f"{m}:vgg19-random r3+r4": (m, {"texture_net": "vgg19", "vgg19_weights": "random",
                                            "mrf_layers": ("relu3_1", "relu4_1"), **MRF1}) for m in ("facetex", "mrf")},
    },
    "structure": {
        "none": ("facetex", {"structure_weight": 0.0, **MRF1}),
        **{f"{'+'.join(ls)} w1": ("facetex", {"structure_layers": ls, "structure_weight": 1.0, **MRF1})
           for ls in (("level1",), ("level2",), ("level3",), ("level2", "level3"), ("level3", "level4"))},
        **{f"{'+'.join(ls)} w{w:g}": ("facetex", {"structure_layers": ls, "structure_weight": w, **MRF1})
           for ls in (("level2", "level3"), ("level3",)) for w in (0.3, 3.0)},
        "level3+level4 w3": ("facetex", {"structure_layers": ("level3", "level4"), "structure_weight": 3.0, **MRF1}),
    },
    "weights": {
        "gatys style 1": ("gatys", {"style_weight": 1.0}),  # the defaults before this study
        "mrf": ("mrf", {}),
        "facetex mrf 1": ("facetex", {"mrf_weight": 1.0}),
        # tuning candidates (the same weights for every pair)
        **{f"gatys style {w:g}": ("gatys", {"style_weight": w}) for w in (0.1, 0.3)},
        **{f"facetex mrf {w:g}": ("facetex", {"mrf_weight": w}) for w in (2.0, 4.0)},
        "facetex mrf 2 struct l3 w1": ("facetex", {"mrf_weight": 2.0, "structure_layers": ("level3",)}),
    },
    # the chosen defaults at the full default schedule: run with --size 384 --iters 100,100,100
    "verify": {m: (m, {}) for m in ("gatys", "mrf", "facetex")},
    "timing": {
        "facetex 384 3x100": ("facetex", {"size": 384, "iters": (100, 100, 100)}),
        "facetex 512 3x100": ("facetex", {"size": 512, "iters": (100, 100, 100)}),
    },
}


# ----------------------------------------------------------------------------- data
def _inputs(pid: str):
    """The 500 px portrait of person ``pid`` and its 68 landmarks (cached as .npy)."""
    cache = OUT / "data"
    cache.mkdir(parents=True, exist_ok=True)
    img_path, pts_path = cache / f"{pid}.png", cache / f"{pid}.npy"
    if not img_path.is_file():
        img = read_image(DATA / f"{pid}_neutral.jpg")
        img = cv2.resize(img, (INPUT_SIZE, INPUT_SIZE), interpolation=cv2.INTER_AREA)
        write_image(img_path, img)
    img = read_image(img_path)
    if not pts_path.is_file():
        np.save(pts_path, detect_face(img).points68)
    return img, np.load(pts_path)


def _key(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-+." else "_" for c in name)


def _stem(name, method, overrides, content_id, style_id, quick) -> str:
    """File stem of a result: the resolved parameters' hash is part of it, so a change of the
    defaults in methods.py re-runs the configuration instead of reusing a stale result."""
    params = preset(method, "default", overrides.get("texture_net")).with_options(
        **{k: v for k, v in {**quick, **overrides}.items() if k != "texture_net"})
    digest = hashlib.sha1(repr(sorted(asdict(params).items())).encode()).hexdigest()[:8]
    return f"{_key(name)}__{content_id}__{style_id}__{digest}"


def run_one(name: str, method: str, overrides: dict, content_id: str, style_id: str, quick: dict) -> dict:
    """One transfer, scored; cached in results/<config>__<content>__<style>.json."""
    res_dir, img_dir = OUT / "results", OUT / "images"
    res_dir.mkdir(parents=True, exist_ok=True)
    img_dir.mkdir(parents=True, exist_ok=True)
    stem = _stem(name, method, overrides, content_id, style_id, quick)
    res_path = res_dir / f"{stem}.json"
    if res_path.is_file():
        return json.loads(res_path.read_text())
    content, pc = _inputs(content_id)
    style, ps = _inputs(style_id)
    options = {**quick, **overrides}
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    out, info = transfer_with_info(content, style, method=method, preset="default", seed=0,
                                   content_points=pc, style_points=ps, **options)
    wall = time.perf_counter() - t0
    out = to_uint8(out).astype(np.float32) / 255.0  # score what is saved
    write_image(img_dir / f"{stem}.png", out)
    try:
        metrics = transfer_metrics(out, content, style, points=(None, pc, ps))
        metrics = {k: float(v) for k, v in metrics.items()}
    except Exception as e:  # no face found in the output counts as a failure, not a crash
        metrics = {"error": str(e)}
    rec = {"name": name, "method": method, "options": {k: list(v) if isinstance(v, tuple) else v
                                                         for k, v in options.items()},
           "content": content_id, "style": style_id, "wall_s": wall, "timings": info["timings"],
           "load_before": load0, "load_after": os.getloadavg()[0], "metrics": metrics,
           "working_shape": info["working_shape"]}
    res_path.write_text(json.dumps(rec, indent=1))
    return rec


# ----------------------------------------------------------------------------- report
COLS = ("E_content", "E_style", "S_content", "S_style", "identity_content", "identity_style")


def baseline(pairs) -> dict:
    """Metrics of the unchanged content image against its style (the "no transfer" row)."""
    path = OUT / "results" / "_baseline.json"
    cache = json.loads(path.read_text()) if path.is_file() else {}
    for c, s in pairs:
        if f"{c}-{s}" not in cache:
            content, pc = _inputs(c)
            style, ps = _inputs(s)
            cache[f"{c}-{s}"] = {k: float(v) for k, v in
                                 transfer_metrics(content, content, style, points=(pc, pc, ps)).items()}
    path.write_text(json.dumps(cache, indent=1))
    return {k: float(np.mean([cache[f"{c}-{s}"][k] for c, s in pairs])) for k in COLS}


def summary(study: str, records: dict, pairs) -> str:
    lines = [f"| config | {' | '.join(COLS)} | id<0.6 | wall s | load |",
             "|---" * (len(COLS) + 4) + "|"]
    base = baseline(pairs)
    lines.append("| content (no transfer) | " + " | ".join(
        f"{base[k]:.1f}" if k.startswith("E") else f"{base[k]:.3f}" for k in COLS) + " | | | |")
    for name, recs in records.items():
        ok = [r for r in recs if "error" not in r["metrics"]]
        vals = [np.mean([r["metrics"][k] for r in ok]) if ok else float("nan") for k in COLS]
        same = sum(r["metrics"]["identity_content"] < 0.6 for r in ok)
        wall = np.mean([r["wall_s"] for r in recs])
        load = np.mean([(r["load_before"] + r["load_after"]) / 2 for r in recs])
        fails = len(recs) - len(ok)
        cells = [f"{v:.1f}" if k.startswith("E") else f"{v:.3f}" for k, v in zip(COLS, vals)]
        lines.append(f"| {name}{f' ({fails} failed)' if fails else ''} | {' | '.join(cells)} | "
                     f"{same}/{len(ok)} | {wall:.0f} | {load:.1f} |")
    head = (f"# {study}: means over {len(pairs)} FRL pairs {', '.join(f'{c}←{s}' for c, s in pairs)}\n\n"
            "E px² at 1000 px (lower E_content = content structure kept), S Eq. 8 (higher S_style = style "
            "texture), identity = dlib descriptor distance; wall = seconds per run; load = 1-min load "
            "average during the run (2 cores).\n\n")
    return head + "\n".join(lines) + "\n"


def grids(study: str, records: dict, pairs, quick: dict) -> None:
    """Per pair: style, content, then every configuration — the content's face crop, 320 px."""
    for c, s in pairs:
        content, pc = _inputs(c)
        style, ps = _inputs(s)
        x0, y0, x1, y1 = face_crop_box(pc, content.shape)
        sx0, sy0, sx1, sy1 = face_crop_box(ps, style.shape)
        row = [style[sy0:sy1, sx0:sx1], content[y0:y1, x0:x1]]
        titles = [f"style {s}", f"content {c}"]
        for name in records:
            method, overrides = STUDIES[study][name]
            p = OUT / "images" / f"{_stem(name, method, overrides, c, s, quick)}.png"
            row.append(read_image(p)[y0:y1, x0:x1] if p.is_file() else None)
            titles.append(name)
        per_row = 4
        rows = [row[i:i + per_row] for i in range(0, len(row), per_row)]
        labels = [titles[i:i + per_row] for i in range(0, len(titles), per_row)]
        write_image(OUT / f"{study}_{c}-{s}.png", image_grid(rows, cell_labels=labels, cell=320))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("study", choices=sorted(STUDIES))
    ap.add_argument("--only", default="", help="comma-separated configuration names (default: all)")
    ap.add_argument("--pairs", type=int, default=len(PAIRS))
    ap.add_argument("--size", type=int, default=QUICK["size"])
    ap.add_argument("--iters", default="40,40,40")
    ap.add_argument("--threads", type=int, default=1,
                    help="torch threads (default 1: on a shared 2-core machine 2 threads ran 3-8x slower)")
    ap.add_argument("--report-only", action="store_true", help="only summarise the cached results")
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(args.threads)
    quick = {"size": args.size, "iters": tuple(int(i) for i in args.iters.split(","))}
    configs = STUDIES[args.study]
    only = [n for n in args.only.split(",") if n]
    names = [n for n in configs if not only or n in only]
    pairs = PAIRS[:args.pairs]
    records: dict[str, list] = {}
    for name in names:
        method, overrides = configs[name]
        for c, s in pairs:
            path = OUT / "results" / f"{_stem(name, method, overrides, c, s, quick)}.json"
            if args.report_only and not path.is_file():
                continue
            rec = run_one(name, method, overrides, c, s, quick)
            records.setdefault(name, []).append(rec)
            m = rec["metrics"]
            print(f"{name:28s} {c}<-{s} wall {rec['wall_s']:5.0f}s load {rec['load_before']:.1f} "
                  + (" ".join(f"{k}={m[k]:.3f}" for k in COLS) if "error" not in m else m["error"]),
                  flush=True)
    if not records:
        return 0
    text = summary(args.study, records, pairs)
    (OUT / f"{args.study}.md").write_text(text)
    grids(args.study, records, pairs, quick)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
