"""``facetex bench transfer|persona|puppet`` — the paper-style evaluations."""

from __future__ import annotations

import importlib

BENCHES = ("transfer", "persona", "puppet")


def register(sub) -> None:
    p = sub.add_parser("bench", help="run an evaluation benchmark (tables, figures)")
    bench_sub = p.add_subparsers(dest="bench", metavar="BENCH")
    bench_sub.required = True
    for name in BENCHES:
        try:
            module = importlib.import_module(f"facetex.bench.{name}")
        except ImportError:  # pragma: no cover - a bench whose dependencies are missing
            continue
        module.register_bench(bench_sub)
