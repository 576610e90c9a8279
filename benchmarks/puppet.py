"""Timings of persona puppetry (Tom Hanks §6 "Runtime"; targets of the puppetry issue).

    python benchmarks/puppet.py --persona BUSH.persona [--driver CLIP.mpg] [--size 256]
    python benchmarks/puppet.py --data DATA   (driver DATA/grid/bbaf2n.mpg, persona built from
                                               DATA/lfw/George_W_Bush and cached; or FACETEX_DATA)

* one core (OMP/MKL/OpenBLAS = 1, cv2.setNumThreads(1)), median over the clip's frames:
  - deformed puppet mesh per frame incl. Huber-ROF denoising and the lip landmarks
    (target <= 0.05 s; paper 0.2 s);
  - texture per frame (Eq. 3 weights, multi-scale blend; target <= 0.1 s; paper 0.34 s);
  - rendering + compositing per frame at --size: the puppet layers (rasterization, texture,
    normals), the composite into the driver's frame (mask, colour, Poisson, mouth interior),
    and face mode (2x supersampled);
* end to end on 2 cores: the wall time of the `facetex puppet` command (a fresh process with
  OMP_NUM_THREADS=2; the command runs BLAS on one thread) incl. imports, persona load, decode,
  tracking, rendering, compositing and H.264 encode, at --size (target >= 13 fps, the puppetry
  issue), with the expression-dependent texture (regional weights, the default; and the paper's
  global weights) and, as the baseline of the same run, the static average texture.
The machine's load average is printed before and after: on a shared machine the wall times
are upper bounds.
"""

from __future__ import annotations

import os
import sys

# the per-stage timings run on one core (set before numpy loads); the end-to-end runs set 2 threads
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

CACHE = Path(__file__).resolve().parent / "out" / "puppet"


def _data(arg) -> Path:
    root = arg or os.environ.get("FACETEX_DATA")
    if not root:
        raise SystemExit("give --data DIR (with grid/ and lfw/George_W_Bush/) or set FACETEX_DATA, "
                         "or give --persona and --driver")
    return Path(root)


def persona_path(arg, data) -> Path:
    if arg:
        return Path(arg)
    from facetex.persona import build_persona

    from facetex.persona import load_persona, read_persona_header

    p = CACHE / "George_W_Bush.persona"
    if not p.is_file():
        CACHE.mkdir(parents=True, exist_ok=True)
        build_persona(_data(data) / "lfw" / "George_W_Bush", jobs=1).save(p, overwrite=True)
    elif not read_persona_header(p).get("texture_stacks"):  # cached by an older facetex: add the stacks
        load_persona(p).save(p, overwrite=True)
    return p


def cli_run(persona: str, driver: str, size: int, texture: str, weights: str = "regional") -> tuple[float, dict]:
    """Wall time of the `facetex puppet` command in a fresh process with 2 threads (2 cores)."""
    env = dict(os.environ, OMP_NUM_THREADS="2", OPENBLAS_NUM_THREADS="2", MKL_NUM_THREADS="2")
    exe = Path(sys.executable).with_name("facetex")
    with tempfile.TemporaryDirectory() as d:
        cmd = [str(exe), "puppet", "--driver", driver, "--puppet", persona, "-o", str(Path(d) / "out.mp4"),
               "--size", str(size), "--texture", texture, "--weights", weights,
               "--json", "-q"]  # the report: JSON only with --json
        t0 = time.perf_counter()
        res = subprocess.run(cmd, env=env, capture_output=True, text=True)
        wall = time.perf_counter() - t0
    if res.returncode:
        raise SystemExit(f"facetex puppet failed: {res.stderr.strip()}")
    return wall, json.loads(res.stdout)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", help="data folder (default $FACETEX_DATA): grid/ and lfw/George_W_Bush/")
    ap.add_argument("--persona", help="puppet .persona (default: built from DATA/lfw/George_W_Bush, cached)")
    ap.add_argument("--driver", help="driver clip (default DATA/grid/bbaf2n.mpg)")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--runs", type=int, default=3, help="end-to-end runs per texture (median reported)")
    args = ap.parse_args(argv)
    args.persona = str(persona_path(args.persona, args.data))
    args.driver = args.driver or str(_data(args.data) / "grid" / "bbaf2n.mpg")
    load_before = os.getloadavg()
    cv2.setNumThreads(1)
    from facetex.persona import load_persona
    from facetex.puppet.puppetry import TEXTURE_BATCH, output_size, prepare_puppetry

    persona = load_persona(args.persona)
    t0 = time.perf_counter()
    s = prepare_puppetry(args.driver, persona)
    prep = time.perf_counter() - t0
    pup = s.puppeteer
    W, H, scale = output_size(s.track.frame_size, args.size)
    from facetex.io import iter_video_frames

    panels = [cv2.resize(f, (W, H), interpolation=cv2.INTER_AREA)
              for f in iter_video_frames(args.driver, max_frames=len(s.motion))]
    mesh_t, tex_t, lay_t, comp_t, face_t = [], [], [], [], []
    for i in range(len(s.motion)):
        t0 = time.perf_counter()
        g = pup.grid(i)
        t1 = time.perf_counter()
        tex = pup.texture(i)
        t2 = time.perf_counter()
        pup.layers(i, g, tex, (W, H), scale, pup.params.supersample_composite)
        t3 = time.perf_counter()
        if s.track.found[i]:
            pup.render(i, g, tex, panels[i], scale)
        t4 = time.perf_counter()
        if s.track.found[i]:
            pup.render(i, g, tex, panels[i], scale, "face")
        t5 = time.perf_counter()
        mesh_t.append(t1 - t0)
        tex_t.append(t2 - t1)
        lay_t.append(t3 - t2)
        comp_t.append(t4 - t3)
        face_t.append(t5 - t4)
    # what the render pass does: textures blended in batches (the default regional weights)
    t0 = time.perf_counter()
    for i0 in range(0, len(s.motion), TEXTURE_BATCH):
        pup.textures(range(i0, min(i0 + TEXTURE_BATCH, len(s.motion))))
    tex_batch = (time.perf_counter() - t0) / len(s.motion)
    # the paper's global weights, same frames (their own precomputation, alpha 1, timed apart)
    from dataclasses import replace

    from facetex.persona import prepare_persona

    pup.params = replace(pup.params, weights="global")
    t0 = time.perf_counter()
    prepare_persona(persona, pup.params.texture_params())
    prep_global = time.perf_counter() - t0
    tex_global = []
    for i in range(len(s.motion)):
        t0 = time.perf_counter()
        pup.texture(i)
        tex_global.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    for i0 in range(0, len(s.motion), TEXTURE_BATCH):
        pup.textures(range(i0, min(i0 + TEXTURE_BATCH, len(s.motion))))
    tex_batch_global = (time.perf_counter() - t0) / len(s.motion)
    from facetex.persona import read_persona_header

    head = read_persona_header(args.persona)
    stacks = head.get("texture_stacks") or {}
    stored = "stored texture stacks" if stacks else "NO stored texture stacks (computed at start)"
    if stacks and not (stacks.get("gaze") and stacks.get("band_energy")):
        stored += " without the photos' gaze and band energy (computed at start: rebuild it for a faster start)"
    print(f"persona: {args.persona} ({len(persona)} photos, format {head['version']}, {stored}); driver "
          f"{args.driver} ({len(s.motion)} frames); load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"{'step (1 core)':50s} {'median ms':>10s} {'p90 ms':>8s}  target")
    for name, t, target in (("deformed puppet mesh (transfer + Huber-ROF + lips)", mesh_t, "<= 50"),
                            ("texture, one frame alone (regional weights)", tex_t, "<= 100"),
                            ("texture, one frame alone (paper's global Eq. 3)", tex_global, "<= 100"),
                            (f"puppet layers at {W}x{H} (raster, texture, normals)", lay_t, ""),
                            (f"composite mode, render + composite at {W}x{H}", comp_t, ""),
                            (f"face mode, render (2x supersampled) at {W}x{H}", face_t, "")):
        print(f"{name:50s} {1000 * np.median(t):10.1f} {1000 * np.percentile(t, 90):8.1f}  {target}")
    print(f"{'texture, batches of %d frames (mean per frame)' % TEXTURE_BATCH:50s} {1000 * tex_batch:10.1f} "
          f"{'':8s}  <= 100  ({np.median(tex_t) / tex_batch:.1f}x faster than one alone)")
    print(f"{'  the same with the global weights':50s} {1000 * tex_batch_global:10.1f} {'':8s}  "
          f"(their precomputation {prep_global:.1f} s, not needed by the default)")
    print(f"one-time setup (1 core): {prep:.1f} s  " + json.dumps({k: round(v, 2) for k, v in s.timings.items()}))
    print(f"\nend to end: `facetex puppet --size {args.size}` in a fresh process, 2 threads on {os.cpu_count()} cores "
          f"(imports, persona load, tracking, rendering, H.264 encode), median of {args.runs}")
    print(f"{'texture':8s} {'frames':>6s} {'wall s':>7s} {'fps':>6s}  stage times (s, overlapping)")
    walls = {}
    kinds = (("static", "static", "regional"), ("ours", "ours", "regional"), ("global", "ours", "global"))
    runs = {label: [] for label, _, _ in kinds}
    for _ in range(max(1, args.runs)):  # interleaved: the machine's speed drifts over minutes
        for label, texture, weights in kinds:
            runs[label].append(cli_run(args.persona, args.driver, args.size, texture, weights))
    for label, texture, weights in kinds:
        wall, rep = sorted(runs[label], key=lambda r: r[0])[len(runs[label]) // 2]
        walls[label] = wall
        n = rep["frames"]
        keys = ("track_s", "persona_load_s", "persona_prepare_s", "puppet_wait_s", "motion_s", "render_pass_s")
        print(f"{label:8s} {n:6d} {wall:7.2f} {n / wall:6.2f}  " +
              " ".join(f"{k[:-2]}={rep['timings'].get(k, 0):.2f}" for k in keys) +
              "  (runs: " + ", ".join(f"{r[0]:.2f}" for r in runs[label]) + ")")
    print("(ours: --texture ours, regional weights, the default; global: --weights global, the paper's Eq. 2/3)")
    print(f"expression-dependent texture costs {walls['ours'] / walls['static']:.2f}x the static texture's wall time "
          f"({walls['global'] / walls['static']:.2f}x with the global weights); "
          f"target >= 13 fps end to end: {'met' if n / walls['ours'] >= 13 else 'NOT met'}")
    load_after = os.getloadavg()
    print(f"load average (1, 5, 15 min) before: {load_before[0]:.1f} {load_before[1]:.1f} {load_before[2]:.1f}, "
          f"after: {load_after[0]:.1f} {load_after[1]:.1f} {load_after[2]:.1f} on {os.cpu_count()} cores"
          + ("  -- the machine was busy: wall times are upper bounds" if max(load_before[0], load_after[0]) > 1.5
             else ""))


if __name__ == "__main__":
    main()
