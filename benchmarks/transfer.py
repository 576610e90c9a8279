"""Transfer speed and memory targets (FaceTex issue), printed as a table.

    python benchmarks/transfer.py [--data DATA] [--content 004] [--style 005]
                                  [--iters 100,100,100] [--skip-vgg] [--skip-memory] [--paper]
                                  [--repeats 2] [--skip-before]

Rows:
- issue 22 (speed): the default preset before that issue (3 × 100 iterations run through, no
  shading or marks step: reproduced with options), the default preset now (target ≤ 20 s wall on
  2 quiet cores) and ``--preset preview`` (≤ 5 s), run interleaved ``--repeats`` times (before,
  now, preview, before, now, …) so that a shared machine's load hits them alike; wall and CPU
  seconds (user + system of the child) are both reported, the median over the repeats;
- default preset (face crop, 384 px, 3 levels × 100 L-BFGS iterations) with the default texture
  network (detail stage included), and the same run with the VGG-19 architecture (random
  weights: timing only); target ≤ 45 s wall on 2 CPU cores for a 1000 px portrait (issue 11;
  the authors' CNNMRF default took 101 s on a Titan X);
- with ``--paper``: the paper preset's whole schedule (1000 px, 3 levels × 200 iterations or
  its convergence test); target ≤ 10 min;
- peak RSS of the paper preset at 1000 px (whole image), run in a fresh process with 2 iterations
  per level (memory does not grow with iterations), against its estimate; target ≤ 8 GB.
The MRF-loss cost ratio and the pystiche comparison are in benchmarks/mrf_loss.py.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
# the default preset as it was before issue 22: 3 x 100 iterations run through (a convergence
# check that never fires), no shading or marks step
BEFORE_ISSUE22 = {"iters": [100, 100, 100], "converge": [100, 0.0], "keep_shading": False, "marks": "off"}

CHILD = r"""
import json, resource, sys, time, warnings
warnings.simplefilter("ignore")
import facetex
from facetex.transfer import estimate_transfer_memory, preset
args = json.loads(sys.argv[1])
if args.get("threads"):
    import torch
    torch.set_num_threads(int(args["threads"]))
c = facetex.read_image(args["content"]); s = facetex.read_image(args["style"])
from facetex.landmarks import detect_face
pc, ps = detect_face(c).points68, detect_face(s).points68  # models loaded before the clock starts
r0 = resource.getrusage(resource.RUSAGE_SELF)
t0 = time.perf_counter()
out, info = facetex.transfer_with_info(c, s, method=args["method"], preset=args["preset"], seed=0, **args["options"])
wall = time.perf_counter() - t0
r1 = resource.getrusage(resource.RUSAGE_SELF)
cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
peak = r1.ru_maxrss * 1024
print(json.dumps({"wall_s": wall, "cpu_s": cpu, "peak_bytes": peak, "estimate_bytes": info["memory_estimate_bytes"],
                  "timings": info["timings"],
                  "optimize_s": info["timings"]["optimize_s"], "align_s": info["timings"]["align_s"],
                  "working_shape": info["working_shape"],
                  "evaluations": sum(l["evaluations"] for l in info["levels"]),
                  "stops": "; ".join(f"{l['iterations']} it {l['stop']}" for l in info["levels"])}))
"""


THREADS = 0  # torch threads in the child (0: torch's default); --threads


def run_child(content, style, method, preset, options) -> dict:
    arg = json.dumps({"content": str(content), "style": str(style), "method": method, "preset": preset,
                      "options": options, "threads": THREADS})
    res = subprocess.run([sys.executable, "-c", CHILD, arg], capture_output=True, text=True, env=os.environ)
    if res.returncode != 0:
        raise SystemExit(f"child failed: {res.stderr.strip().splitlines()[-1] if res.stderr else res.returncode}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", help="data root holding frl-london/ or the folder itself (default $FACETEX_DATA)")
    ap.add_argument("--content", default="004")
    ap.add_argument("--style", default="005")
    ap.add_argument("--iters", default="100,100,100")
    ap.add_argument("--skip-vgg", action="store_true")
    ap.add_argument("--skip-memory", action="store_true")
    ap.add_argument("--paper", action="store_true", help="also time the paper preset's whole schedule")
    ap.add_argument("--repeats", type=int, default=2, help="interleaved repeats of the issue-22 speed rows")
    ap.add_argument("--skip-before", action="store_true", help="issue-22 rows: skip the pre-issue default")
    ap.add_argument("--only-speed", action="store_true", help="only the issue-22 speed rows")
    ap.add_argument("--threads", type=int, default=0,
                    help="torch threads in each run (default torch's: one per core); on a shared, loaded machine "
                         "1 avoids oversubscription and its CPU seconds are the work itself")
    a = ap.parse_args()
    global THREADS
    THREADS = a.threads
    from facetex.bench._common import data_folder, data_root  # --data or $FACETEX_DATA, never a machine path
    a.data = str(data_folder(data_root(a.data), "frl-london"))
    content = Path(a.data) / f"{a.content}_neutral.jpg"
    style = Path(a.data) / f"{a.style}_neutral.jpg"
    iters = [int(v) for v in a.iters.split(",")]
    rows = []
    load = os.getloadavg()[0]
    speed = {"before": [], "default": [], "preview": []}
    for _ in range(max(1, a.repeats)):  # interleaved: a shared machine's load hits every row alike
        if not a.skip_before:
            speed["before"].append(run_child(content, style, "facetex", "default", BEFORE_ISSUE22))
        speed["default"].append(run_child(content, style, "facetex", "default", {}))
        speed["preview"].append(run_child(content, style, "facetex", "preview", {}))
    print(f"\nissue 22 speed, {content.stem} <- {style.stem}, median of {max(1, a.repeats)} interleaved runs; load "
          f"average {load:.2f} at start, {os.getloadavg()[0]:.2f} at the end (2 cores)\n")
    print("| run | evaluations | levels (iterations, stop) | align s | optimise s | detail s | finish s | wall s "
          "| CPU s | target |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, target in (("before", "(was 30-32 s)"), ("default", "≤ 20 s"), ("preview", "≤ 5 s")):
        runs = speed[name]
        if not runs:
            continue
        med = lambda k: float(np.median([r[k] for r in runs]))  # noqa: E731
        medt = lambda k: float(np.median([r["timings"].get(k, 0.0) for r in runs]))  # noqa: E731
        print(f"| {name} | {runs[0]['evaluations']} | {runs[0]['stops']} | {medt('align_s'):.1f} | "
              f"{medt('optimize_s'):.1f} | {medt('detail_s'):.1f} | {medt('finish_s'):.1f} | {med('wall_s'):.1f} | "
              f"{med('cpu_s'):.1f} | {target} |")
    if a.only_speed:
        return
    r = run_child(content, style, "facetex", "default", {"iters": iters})
    rows.append(("facetex default, effnet-lite0", r, "≤ 45 s"))
    if not a.skip_vgg:
        r = run_child(content, style, "facetex", "default",
                      {"iters": iters, "texture_net": "vgg19", "vgg19_weights": "random"})
        rows.append(("facetex default, VGG-19 (random)", r, "timing only"))
    if not a.skip_memory:
        r = run_child(content, style, "facetex", "paper", {"iters": [2, 2, 2]})
        rows.append(("facetex paper preset, 1000 px, 2 it/level", r, "peak ≤ 8 GB"))
    if a.paper:
        r = run_child(content, style, "facetex", "paper", {})
        rows.append((f"facetex paper preset, whole schedule ({r['stops']})", r, "≤ 600 s"))
    print(f"\nload average at start: {load:.2f} (2 cores)\n")
    print("| run | working px | evaluations | align s | optimise s | wall s | peak RSS GB | estimate GB | target |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, r, target in rows:
        print(f"| {name} | {r['working_shape'][1]}x{r['working_shape'][0]} | {r['evaluations']} | {r['align_s']:.1f} | "
              f"{r['optimize_s']:.1f} | {r['wall_s']:.1f} | {r['peak_bytes'] / 1e9:.2f} | "
              f"{r['estimate_bytes'] / 1e9:.2f} | {target} |")


if __name__ == "__main__":
    main()
