"""Transfer speed and memory targets (FaceTex issue), printed as a table.

    python benchmarks/transfer.py [--data DATA] [--content 004] [--style 005]
                                  [--iters 100,100,100] [--skip-vgg] [--skip-memory] [--paper]

Rows:
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

HERE = Path(__file__).resolve().parent

CHILD = r"""
import json, resource, sys, time, warnings
warnings.simplefilter("ignore")
import facetex
from facetex.transfer import estimate_transfer_memory, preset
args = json.loads(sys.argv[1])
c = facetex.read_image(args["content"]); s = facetex.read_image(args["style"])
t0 = time.perf_counter()
out, info = facetex.transfer_with_info(c, s, method=args["method"], preset=args["preset"], seed=0, **args["options"])
wall = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"wall_s": wall, "peak_bytes": peak, "estimate_bytes": info["memory_estimate_bytes"],
                  "optimize_s": info["timings"]["optimize_s"], "align_s": info["timings"]["align_s"],
                  "working_shape": info["working_shape"],
                  "evaluations": sum(l["evaluations"] for l in info["levels"]),
                  "stops": "; ".join(f"{l['iterations']} it {l['stop']}" for l in info["levels"])}))
"""


def run_child(content, style, method, preset, options) -> dict:
    arg = json.dumps({"content": str(content), "style": str(style), "method": method, "preset": preset,
                      "options": options})
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
    a = ap.parse_args()
    from facetex.bench._common import data_folder, data_root  # --data or $FACETEX_DATA, never a machine path
    a.data = str(data_folder(data_root(a.data), "frl-london"))
    content = Path(a.data) / f"{a.content}_neutral.jpg"
    style = Path(a.data) / f"{a.style}_neutral.jpg"
    iters = [int(v) for v in a.iters.split(",")]
    rows = []
    load = os.getloadavg()[0]
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
