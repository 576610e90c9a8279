"""Batch engines on 20 small transfers: local 1 worker, local 2 workers, Ray with 2 CPUs.

The same 20 (content, style) pairs (FaceTex, --size 128, --iters 10,10,10 by default) run through
``facetex.batch.run_batch`` on each engine, each into a fresh folder. Printed per engine: items
per minute over the run (worker start-up and model loading included; the engine's own start,
e.g. ``ray.init``, reported apart), the speed-up over local 1 worker (target >= 1.7 with 2
workers on a 2-core machine), the first item's time (start-up), the per-item scheduling
overhead on Ray (time from submit to result minus the time the item ran inside the worker;
target <= 0.5 s), the peak resident memory of a worker, and whether the outputs equal local
2 workers' bit for bit. "local 1 worker" gets all CPUs as torch threads (``cpus // workers``), so
its bytes differ from the one-thread engines' (torch's float sums depend on the thread count: "no"
in that column is expected; ``facetex batch`` gives every item one thread unless
``--cpus-per-item`` says otherwise); "local 1 worker, 1 thread" is the same worker budget as each
of the 2 workers (pool scaling). The workers' OpenMP threads wait passively (``OMP_WAIT_POLICY=PASSIVE``,
as under the command line, unless set): spinning threads collapse on a shared machine, but sleeping
ones make the 2-thread worker slower at 128 px, so the speed-up over "local 1 worker" alone flatters
2 workers; run ``local1x1`` too and the speed-up over the faster 1-worker run is printed as well.
The machine's load average before and after each engine is printed: the speed-up of a shared
machine is only as good as its idle cores. So are printed what does not depend on it as much: the
median CPU seconds per item (all threads of the worker; more CPU per item with more workers is
contention: caches, memory bandwidth, oversubscribed thread pools), each worker's start-up (spawn to
its first item) and its idle time (spawn to the end of the run, minus its items).

Fairness: every engine runs the same items; an untimed warm-up run first (2 items, 1 worker) reads
the models, libraries and images into the page cache and makes facetex's cache file, so that the
first engine measured does not pay for a cold cache; with ``--repeat`` the engines are interleaved
and every other repetition runs them in the reverse order (drift of a shared machine's speed hits
both alike). Besides the speed-up of the median runs, the ratio of each repetition's pair of runs
is printed.

    python benchmarks/batch.py [--data DATA] [--pairs 20] [--size 128] [--iters 10,10,10]

DATA (or $FACETEX_DATA) is the data root holding ``frl-london/`` or a folder of ``NNN_neutral.jpg``
portraits: the pairs are of different people, chosen as ``facetex bench transfer`` chooses them.
Without either, the bundled samples (every image with every other, 30 ordered pairs).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def worker_times(stats: list, t_begin: float, t_end: float) -> tuple[float, float]:
    """(start-up s, idle s) summed over the workers of a run: a local worker's start-up is from
    its spawn to its first item, its idle time from its spawn (or the run's start) to the run's
    end minus the seconds of its items. Ray's workers are not ours: both from the run's start."""
    start_s = idle_s = 0.0
    for pid in {r["pid"] for r in stats}:
        rs = sorted((r for r in stats if r["pid"] == pid), key=lambda r: r["started"])
        t0 = max(t_begin, rs[0].get("worker_spawned") or t_begin)
        start_s += rs[0]["started"] - t0
        idle_s += (t_end - t0) - sum(r["seconds"] for r in rs)
    return start_s, idle_s


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", help="data root holding frl-london/, or a folder of NNN_neutral.jpg portraits "
                                   "(default: $FACETEX_DATA, else the bundled samples)")
    ap.add_argument("--pairs", type=int, default=20)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--iters", default="10,10,10")
    ap.add_argument("--engines", default="local1x1,local1,local2,ray2",
                    help="comma-separated subset of local1x1,local1,local2,ray2")
    ap.add_argument("--repeat", type=int, default=1,
                    help="run the engines this many times, interleaved (the run with the median time is reported: "
                         "a shared machine's speed drifts)")
    ap.add_argument("--warmup", type=int, default=2,
                    help="items of the untimed warm-up run (1 worker) before the measured ones; 0: none")
    ap.add_argument("--keep", help="keep the output folders under this folder")
    args = ap.parse_args()

    from facetex._parallel import available_cpus
    from facetex._resources import sample_path
    from facetex.batch import LocalEngine, RayEngine, pairs_from_folders, run_batch, transfer_items

    if args.data or os.environ.get("FACETEX_DATA"):
        from facetex.bench._common import data_folder, data_root, list_portraits, select_pairs

        data = data_folder(data_root(args.data), "frl-london")
        portraits = list_portraits(data, tag="neutral")
        rows = [{"content": str(portraits[c]), "style": str(portraits[s]), "source": f"{c} x {s}"}
                for c, s in select_pairs(list(portraits), args.pairs)]
    else:
        data = sample_path()
        rows = pairs_from_folders(data, data, args.pairs)
    if len(rows) < args.pairs:
        print(f"only {len(rows)} pairs in {data} (asked {args.pairs})")
    iters = tuple(int(v) for v in args.iters.split(","))
    cpus = available_cpus()
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="facetex-batch-bench-"))
    root.mkdir(parents=True, exist_ok=True)
    configs = {"local1x1": ("local, 1 worker, 1 thread", lambda: LocalEngine(1, threads=1)),
               "local1": ("local, 1 worker", lambda: LocalEngine(1)),
               "local2": ("local, 2 workers", lambda: LocalEngine(2)),
               "ray2": ("Ray, 2 CPUs (local Ray)", lambda: RayEngine(num_cpus=2))}
    results = []
    print(f"{len(rows)} pairs from {data}, size {args.size}, iters {args.iters}, {cpus} CPUs available; "
          f"outputs in {root}")
    if args.warmup > 0:  # the same warm page cache (models, libraries, images) for every engine measured
        out = root / "warmup"
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir()
        t0 = time.perf_counter()
        with LocalEngine(1, threads=1) as engine:
            run_batch(transfer_items(rows[:args.warmup], out, size=args.size, iters=iters), out, engine)
        print(f"  warm-up ({min(args.warmup, len(rows))} items, not measured): {time.perf_counter() - t0:.1f} s",
              flush=True)
    names = args.engines.split(",")
    order = [(r, n) for r in range(max(1, args.repeat)) for n in (names if r % 2 == 0 else names[::-1])]
    for rep, name in order:
        title, make = configs[name]
        out = root / f"{name}-{rep}"
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir()
        before = load()
        t0 = time.perf_counter()
        engine = make()
        with engine:
            t_start = time.perf_counter() - t0
            t_begin = time.time()
            s = run_batch(transfer_items(rows, out, size=args.size, iters=iters), out, engine)
            t_end = time.time()
            desc = engine.describe()
        assert s.ok and s.done == len(rows), s.as_dict()
        stats = s.item_stats
        overhead = [r["overhead_s"] for r in stats]
        startup_s, idle_s = worker_times(stats, t_begin, t_end)
        results.append({
            "name": name, "title": title, "slots": desc.get("workers") or desc.get("slots"),
            "threads": desc.get("threads_per_worker") or desc.get("cpus_per_item"), "start_s": t_start,
            "wall_s": s.seconds, "per_min": 60.0 * s.done / s.seconds,
            "first_s": max(r["seconds"] for r in stats), "median_item_s": sorted(r["seconds"] for r in stats)[len(stats) // 2],
            "overhead_mean": sum(overhead) / len(overhead), "overhead_max": max(overhead),
            "rss_mb": max(r["peak_rss_mb"] or 0 for r in stats), "workers_seen": len({r["pid"] for r in stats}),
            "cpu_item_s": statistics.median(r["cpu_s"] for r in stats), "startup_s": startup_s, "idle_s": idle_s,
            "load_before": before, "load_after": load(), "out": out, "rep": rep,
        })
        print(f"  {title}: {s.seconds:.1f} s, CPU s per item {results[-1]['cpu_item_s']:.2f} (median), workers' "
              f"start-up {startup_s:.1f} s, idle {idle_s:.1f} s (summed), load {before} -> {results[-1]['load_after']}",
              flush=True)

    if args.repeat > 1:  # per engine the run with the median time
        runs = {}
        for r in results:
            runs.setdefault(r["name"], []).append(r)
        for name, rs in runs.items():
            walls = ", ".join(f"{r['wall_s']:.1f}" for r in rs)
            print(f"  {name}: run s {walls}")
        if "local1" in runs and "local2" in runs:
            pairs = [a["wall_s"] / b["wall_s"] for a, b in zip(runs["local1"], runs["local2"])]
            print(f"  local1 / local2 per repetition: {', '.join(f'{p:.2f}' for p in pairs)} "
                  f"(median {statistics.median(pairs):.2f})")
        results = [sorted(rs, key=lambda r: r["wall_s"])[(len(rs) - 1) // 2] for rs in runs.values()]
    base = next((r for r in results if r["name"] == "local1"), None)
    ref = next((r for r in results if r["name"] == "local2"), None)

    def same(r):
        if ref is None or r is ref:
            return "–"
        a = sorted(p.name for p in ref["out"].glob("*.png"))
        return "yes" if all((ref["out"] / n).read_bytes() == (r["out"] / n).read_bytes() for n in a) else "no"

    print()
    print("| engine | workers × threads | engine start s | run s | items / min | speed-up vs local 1 | "
          "slowest item s (start-up) | median item s | CPU s / item | workers' start-up, idle s | "
          "overhead / item s (mean, max) | peak RSS / worker MB | outputs = local 2 | load before → after |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---|")
    for r in results:
        speed = f"{r['per_min'] / base['per_min']:.2f}×" if base else "–"
        print(f"| {r['title']} | {r['slots']} × {r['threads']} | {r['start_s']:.1f} | {r['wall_s']:.1f} | "
              f"{r['per_min']:.1f} | {speed} | {r['first_s']:.1f} | {r['median_item_s']:.2f} | "
              f"{r['cpu_item_s']:.2f} | {r['startup_s']:.1f}, {r['idle_s']:.1f} | "
              f"{r['overhead_mean']:.3f}, {r['overhead_max']:.3f} | {r['rss_mb']:.0f} | {same(r)} | "
              f"{r['load_before']} → {r['load_after']} |")
    if base and ref:
        sp = ref["per_min"] / base["per_min"]
        print(f"\nspeed-up with 2 workers over 1 worker with both cores as threads: {sp:.2f}× "
              f"(target >= 1.7: {'met' if sp >= 1.7 else 'NOT met'})")
    one = next((r for r in results if r["name"] == "local1x1"), None)
    if one and ref:
        print(f"speed-up with 2 workers over 1 worker at the same budget per worker (1 thread): "
              f"{ref['per_min'] / one['per_min']:.2f}×")
    if one and base and ref:  # the 2-thread worker waits passively (as under the command line): at 128 px it
        best = max(one, base, key=lambda r: r["per_min"])  # can be slower than 1 thread, which flatters the above
        print(f"speed-up with 2 workers over the faster 1-worker run ({best['title']}): "
              f"{ref['per_min'] / best['per_min']:.2f}×")
    ray = next((r for r in results if r["name"] == "ray2"), None)
    if ray:
        print(f"Ray scheduling overhead per item: mean {ray['overhead_mean']:.3f} s, max {ray['overhead_max']:.3f} s "
              f"(target <= 0.5 s: {'met' if ray['overhead_mean'] <= 0.5 else 'NOT met'})")
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
