"""Estimated vs measured peak memory of ``facetex transfer`` (the ``--max-memory`` check).

Each configuration runs in a fresh ``python`` process (so peaks do not mix): the child
runs :func:`facetex.transfer.transfer_with_info` with a few iterations per level and
reports its peak resident set (``VmHWM`` from /proc/self/status; ``ru_maxrss`` where
there is no /proc), its resident set after imports, and the estimate
(:func:`facetex.transfer.estimate_transfer_memory`, as recorded in the info).
The estimate should be at or above the peak and not far above it. The L-BFGS history is
capped at the iteration count (a short run stores no more pairs), in the estimate too.

Run: ``python benchmarks/memory.py`` (default configurations, ~2-5 min on 2 cores) or
``python benchmarks/memory.py --config facetex:default:256 facetex:paper:768``
(METHOD:PRESET:SIZE[:NET]). Content/style: FRL London 001/002 neutral from
$FACETEX_DATA/frl-london when present, else the bundled samples.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

DATA = Path(__import__("os").environ.get("FACETEX_DATA", "FACETEX_DATA-not-set")) / "frl-london"  # data root: $FACETEX_DATA
DEFAULT_CONFIGS = ["facetex:default:256", "facetex:default:512", "facetex:paper:512", "facetex:paper:768"]


def _images() -> tuple[Path, Path]:
    if (DATA / "001_neutral.jpg").is_file() and (DATA / "002_neutral.jpg").is_file():
        return DATA / "001_neutral.jpg", DATA / "002_neutral.jpg"
    from facetex._resources import sample_path

    return sample_path("frl_004_neutral.jpg"), sample_path("frl_005_neutral.jpg")


def child(config: str, iters: int) -> dict:
    """Run one transfer here; return the numbers (called in the fresh process)."""
    import torch

    from facetex._memory import current_rss, peak_rss
    from facetex.io import read_image
    from facetex.transfer import transfer_with_info
    from facetex.transfer.methods import preset

    method, name, size, *net = config.split(":")
    net = net[0] if net else None
    levels = preset(method, name, net).levels
    content_path, style_path = _images()
    content, style = read_image(content_path), read_image(style_path)
    base = current_rss()
    t = time.perf_counter()
    # With a few iterations L-BFGS stores only that many curvature pairs, so the history is
    # capped to match: the estimate then counts what this short run can hold.
    _, info = transfer_with_info(content, style, method=method, preset=name, texture_net=net, size=int(size),
                                 iters=(iters,) * levels, lbfgs_history=iters, max_memory=1 << 50)
    return {"config": config, "working_shape": info["working_shape"], "levels": levels,
            "estimate": info["memory_estimate_bytes"], "peak": peak_rss(), "base": base,
            "seconds": time.perf_counter() - t, "threads": torch.get_num_threads()}


def measure(config: str, iters: int) -> dict:
    cmd = [sys.executable, __file__, "--child", config, "--iters", str(iters)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        return {"config": config, "error": (r.stderr.strip().splitlines() or ["?"])[-1]}
    res = json.loads(r.stdout.strip().splitlines()[-1])
    # cross-check with the kernel's view of the finished child (max over children so far)
    res["ru_maxrss_children"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", nargs="+", default=DEFAULT_CONFIGS, metavar="METHOD:PRESET:SIZE[:NET]")
    ap.add_argument("--iters", type=int, default=2, help="L-BFGS iterations per level (default 2)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--json", help="also write the rows to this JSON file")
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.child, args.iters)))
        return 0
    mib = 2**20
    rows = []
    print(f"{'config':<24}{'work px':>11}{'estimate':>10}{'peak RSS':>10}{'after import':>13}{'est/peak':>9}"
          f"{'est-base':>9}{'peak-base':>10}{'time':>7}")
    for config in args.config:
        r = measure(config, args.iters)
        rows.append(r)
        if "error" in r:
            print(f"{config:<24} failed: {r['error']}")
            continue
        h, w = r["working_shape"]
        print(f"{config:<24}{f'{w}x{h}':>11}{r['estimate'] / mib:>9.0f}M{r['peak'] / mib:>9.0f}M"
              f"{r['base'] / mib:>12.0f}M{r['estimate'] / r['peak']:>9.2f}"
              f"{(r['estimate'] - 350 * mib) / mib:>8.0f}M{(r['peak'] - r['base']) / mib:>9.0f}M"
              f"{r['seconds']:>6.0f}s", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    print(f"\nestimate: facetex.transfer.estimate_transfer_memory (350 MiB fixed + per-pixel terms);"
          f" peak: VmHWM of a fresh process; {args.iters} iterations per level; {os.cpu_count()} CPUs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
