"""Timings of persona puppetry (Tom Hanks §6 "Runtime"; targets of the puppetry issue).

    python benchmarks/puppet.py --persona BUSH.persona [--driver CLIP.mpg] [--size 256]

* one core (OMP/MKL/OpenBLAS = 1, cv2.setNumThreads(1)), median over the clip's frames:
  - deformed puppet mesh per frame incl. Huber-ROF denoising (target <= 0.05 s; paper 0.2 s);
  - texture per frame (Eq. 3 weights, multi-scale blend; target <= 0.1 s; paper 0.34 s);
  - rendering + compositing per frame at --size;
* end-to-end on 2 cores (a child process with 2 BLAS/OpenCV threads): `puppeteer` on the clip
  incl. decode, tracking, rendering and H.264 encode, at --size (target >= 5 fps), reported
  with and without the one-time per-persona preparation (pyramid stack and average shape,
  cacheable per persona).
Without --persona, a persona is built from /work/shared/data/lfw/George_W_Bush (minutes) and
cached in benchmarks/out/puppet/.
"""

from __future__ import annotations

import os
import sys

if "--child" not in sys.argv:
    for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[_v] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

DEFAULT_DRIVER = "/work/shared/data/grid/bbaf2n.mpg"
DEFAULT_PHOTOS = "/work/shared/data/lfw/George_W_Bush"
CACHE = Path(__file__).resolve().parent / "out" / "puppet"


def persona_path(arg) -> Path:
    if arg:
        return Path(arg)
    from facetex.persona import build_persona

    p = CACHE / "George_W_Bush.persona"
    if not p.is_file():
        CACHE.mkdir(parents=True, exist_ok=True)
        build_persona(DEFAULT_PHOTOS, jobs=1).save(p, overwrite=True)
    return p


def child(args) -> None:
    """End-to-end run with 2 threads (this process was started with the thread env set)."""
    cv2.setNumThreads(2)
    from facetex.persona import load_persona
    from facetex.persona.puppet import puppeteer

    persona = load_persona(args.persona)
    with tempfile.TemporaryDirectory() as d:
        rep = puppeteer(args.driver, persona, Path(d) / "out.mp4", size=args.size, overwrite=True)
    print(json.dumps(rep))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--persona", help="puppet .persona (default: built from LFW George_W_Bush, cached)")
    ap.add_argument("--driver", default=DEFAULT_DRIVER)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        return child(args)
    args.persona = str(persona_path(args.persona))
    cv2.setNumThreads(1)
    from facetex.persona import load_persona
    from facetex.persona.puppet import output_size, prepare_puppetry

    persona = load_persona(args.persona)
    t0 = time.perf_counter()
    s = prepare_puppetry(args.driver, persona)
    prep = time.perf_counter() - t0
    pup = s.puppeteer
    W, H, scale = output_size(s.track.frame_size, args.size)
    bg = np.full((H, W, 3), 0.5, np.float32)
    mesh_t, tex_t, ren_t = [], [], []
    for i in range(len(s.motion)):
        t0 = time.perf_counter()
        v = pup.mesh(i)
        t1 = time.perf_counter()
        tex = pup.texture(i)
        t2 = time.perf_counter()
        pup.render(i, v, tex, bg, scale)
        t3 = time.perf_counter()
        mesh_t.append(t1 - t0)
        tex_t.append(t2 - t1)
        ren_t.append(t3 - t2)
    print(f"persona: {args.persona} ({len(persona)} photos); driver {args.driver} ({len(s.motion)} frames); "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"{'step (1 core)':50s} {'median ms':>10s} {'p90 ms':>8s}  target")
    for name, t, target in (("deformed puppet mesh (transfer + Huber-ROF)", mesh_t, "<= 50"),
                            ("texture (Eq. 3 weights + pyramid blend)", tex_t, "<= 100"),
                            (f"render + composite at {W}x{H}", ren_t, "")):
        print(f"{name:50s} {1000 * np.median(t):10.1f} {1000 * np.percentile(t, 90):8.1f}  {target}")
    print(f"one-time setup (1 core): {prep:.1f} s  " + json.dumps({k: round(v, 2) for k, v in s.timings.items()}))
    env = dict(os.environ, OMP_NUM_THREADS="2", OPENBLAS_NUM_THREADS="2", MKL_NUM_THREADS="2")
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, __file__, "--child", "--persona", args.persona, "--driver", args.driver,
                          "--size", str(args.size)], env=env, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t0
    rep = json.loads(res.stdout.strip().splitlines()[-1])
    tm = rep["timings"]
    n = rep["frames"]
    once = tm.get("persona_prepare_s", 0) + tm.get("puppet_shape_s", 0)
    print(f"end-to-end, 2 cores, {args.size} px: {n} frames in {tm['total_s']:.1f} s (process {wall:.1f} s incl. "
          f"persona load) = {n / tm['total_s']:.2f} fps; without the per-persona setup ({once:.1f} s): "
          f"{n / (tm['total_s'] - once):.2f} fps (target >= 5)")
    print("  " + json.dumps(tm))


if __name__ == "__main__":
    main()
