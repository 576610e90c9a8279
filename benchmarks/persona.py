"""Persona texture speed and memory (Tom Hanks Sec. 6 "Runtime": 0.34 s per texture on one core).

    python benchmarks/persona.py [--data DATA/lfw/George_W_Bush] [--cache DIR]

1. build time per photo on 2 cores (``--build-photos`` photos, jobs = 2; includes the average
   shape's reconstruction and photometric validation);
2. synthesis time per target (``synthesize_texture`` from target fiducials to the texture in
   the canonical frame), median over ``--targets`` targets, one thread (OMP/BLAS/OpenCV = 1),
   per method, for the full persona (>= 500 photos for LFW Bush) and a ``--synth-photos``
   slice, after the one-off precomputation; ours (regional weights) and the paper's Eq. 3
   (global weights) measured in the same run;
3. in-RAM size of the full persona: stored arrays + precomputation, and RSS.
The machine's load average (``/proc/loadavg``) is printed before and after: timings on a
loaded machine are upper bounds. Personas are cached in ``--cache`` (built once). Prints a
Markdown table.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402


def _rss_mb(field: str = "VmRSS") -> float:
    for line in open("/proc/self/status"):
        if line.startswith(field):
            return int(line.split()[1]) / 1024
    return float("nan")


def _load() -> str:
    try:
        return " / ".join(open("/proc/loadavg").read().split()[:3])
    except OSError:
        return "n/a"


def _persona(data: Path, files, cache: Path, jobs: int):
    from facetex.persona import build_persona, load_persona

    if cache.exists():
        return load_persona(cache), None
    t = time.perf_counter()
    p = build_persona(data, files=files, jobs=jobs)
    dt = time.perf_counter() - t
    p.save(cache, overwrite=True)
    return p, dt


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", help="data root holding lfw/George_W_Bush/ or the folder itself (default $FACETEX_DATA)")
    ap.add_argument("--cache", default="bench_out/persona_speed")
    ap.add_argument("--build-photos", type=int, default=60)
    ap.add_argument("--synth-photos", type=int, default=250)
    ap.add_argument("--targets", type=int, default=50)
    args = ap.parse_args()
    from facetex.bench._common import data_folder, data_root  # --data or $FACETEX_DATA, never a machine path
    args.data = str(data_folder(data_root(args.data), 'lfw/George_W_Bush'))
    cv2.setNumThreads(1)
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:
        pass
    from facetex.persona import synthesize_texture
    from facetex.persona.build import _list_photos
    from facetex.persona.stacks import prepare_persona

    load0 = _load()
    data = Path(args.data)
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    files = _list_photos(data)
    rows = []

    # 1. build time per photo, 2 worker processes (pool start-up and model loading included)
    t = time.perf_counter()
    from facetex.persona import build_persona

    small = build_persona(data, files=files[: args.build_photos], jobs=2)
    dt = time.perf_counter() - t
    rows.append((f"build, 2 processes ({args.build_photos} photos, {len(small)} usable)",
                 f"{dt / args.build_photos * 1000:.0f} ms / photo", f"total {dt:.1f} s"))
    del small

    # 2. synthesis per target, one thread: the full persona, and its first --synth-photos photos
    #    (sliced: their alignment is relative to the full collection's mean, irrelevant for timing)
    import dataclasses

    from facetex.persona import TextureParams

    full, dt_full = _persona(data, files, cache / f"{data.name}_all.persona", 2)
    n = min(args.synth_photos, len(full))
    sliced = dataclasses.replace(full, _cache={}, photos=full.photos[:n], **{
        k: getattr(full, k)[:n] for k in ("images", "visibility", "fiducials", "points68", "poses", "flows")})
    methods = (("ours", "ours", TextureParams()), ("paper (global Eq. 3)", "ours", TextureParams.paper()),
               ("static", "static", TextureParams()), ("weighted", "weighted", TextureParams.paper()),
               ("prewarp", "prewarp", TextureParams.paper()))
    for p in (full, sliced):
        rng = np.random.default_rng(0)
        idx = rng.choice(len(p), size=args.targets, replace=len(p) < args.targets)
        targets = [p.fiducials[i] + rng.normal(0, 1.0, (49, 2)) for i in idx]
        for label, method, tp in methods:
            if p is sliced and method in ("weighted", "prewarp"):
                continue
            t = time.perf_counter()
            prepare_persona(p, tp)
            t_prep = time.perf_counter() - t
            synthesize_texture(p, fiducials=targets[0], method=method, params=tp)  # lazy per-method caches
            ts = []
            for f in targets:
                t = time.perf_counter()
                synthesize_texture(p, fiducials=f, method=method, params=tp)
                ts.append(time.perf_counter() - t)
            rows.append((f"synthesize `{label}`, 1 thread, {len(p)}-photo persona, 192x240",
                         f"{np.median(ts) * 1000:.1f} ms / target",
                         f"median of {len(ts)}; p90 {np.percentile(ts, 90) * 1000:.1f} ms; "
                         f"precompute {t_prep:.1f} s (shared between weights with the same alpha)"))
    del sliced

    # 3. memory of the full persona (the precomputation for ours)
    stored = sum(getattr(full, k).nbytes for k in ("images", "visibility", "fiducials", "points68", "poses",
                                                  "flows", "subspace"))
    prep = prepare_persona(full)
    rows.append((f"in-RAM persona, {len(full)} photos: stored arrays", f"{stored / 2**20:.0f} MiB", ""))
    rows.append(("+ precomputation for `ours`", f"{prep.nbytes() / 2**20:.0f} MiB",
                 f"total {(stored + prep.nbytes()) / 2**30:.2f} GiB; peak RSS {_rss_mb('VmHWM'):.0f} MiB "
                 "(all methods' caches)"))
    if dt_full is not None:
        rows.append((f"build, 2 processes ({len(files)} photos)", f"{dt_full / len(files) * 1000:.0f} ms / photo",
                     f"total {dt_full:.0f} s"))
    rows.append(("machine load average (1 / 5 / 15 min)", _load(), f"at the start: {load0}; {os.cpu_count()} CPUs"))
    print("| measurement | value | note |\n|---|---:|---|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
