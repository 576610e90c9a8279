"""Planning time of a batch resume: ``run_batch`` on a folder of N trivial items, all done.

The items are the pairs of ``sqrt(N)`` contents x ``sqrt(N)`` styles (random 50 kB files in
``DIR/in``), each writing a few bytes and a sidecar. The first call makes ``DIR`` and computes
every item once (in this process, untimed); then each of ``--repeat`` resumes is timed (the
whole ``run_batch`` call: listing the outputs, reading the manifest, hashing the inputs,
finding nothing to do). Replace a file in ``DIR/in`` to time a rerun that recomputes its items.

    python benchmarks/batch_resume.py /tmp/resume [--items 10000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

from facetex.batch import InlineEngine, Item, run_batch


def write(p: dict) -> dict:
    """A trivial item: its name as output, its ``batch`` record as sidecar (as the real items)."""
    from facetex.io import write_files

    out, batch = p["output"], p.get("batch") or {}
    write_files({out: p["name"], f"{out}.json": json.dumps({"batch": batch})},
                overwrite=bool(batch.get("replace")), reverse_commit=not batch.get("replace"))
    return {"outputs": [out, f"{out}.json"]}


def items(root: Path, n: int) -> list[Item]:
    side = int(round(n ** 0.5))
    out = []
    for i in range(side * side):
        c, s = root / "in" / f"c{i // side}.jpg", root / "in" / f"s{i % side}.jpg"
        key = f"c{i // side}__s{i % side}"
        o = str(root / "out" / f"{key}.png")
        out.append(Item(key, "test", write, {"name": key, "output": o}, (o, f"{o}.json"),
                        {"content": str(c), "style": str(s)}, inputs=(str(c), str(s))))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--items", type=int, default=10000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    root = args.folder.resolve()
    side = int(round(args.items ** 0.5))
    if not (root / "in").exists():
        (root / "in").mkdir(parents=True)
        for k in range(side):
            for p in "cs":
                (root / "in" / f"{p}{k}.jpg").write_bytes(os.urandom(50_000))
    (root / "out").mkdir(exist_ok=True)
    s = run_batch(items(root, args.items), root / "out", InlineEngine())
    if s.done:
        print(f"computed {s.done} items")
    times = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        s = run_batch(items(root, args.items), root / "out", InlineEngine())
        times.append(time.perf_counter() - t0)
        print(f"resume: {s.skipped_done} done, {s.done} computed ({s.inputs_changed} as an input changed): "
              f"{times[-1]:.2f} s; load {os.getloadavg()[0]:.1f}")
    print(f"median {statistics.median(times):.2f} s, manifest {(root / 'out' / 'manifest.jsonl').stat().st_size} bytes")


if __name__ == "__main__":
    main()
