"""Side-by-side metrics of run folders (``facetex compare`` and the report's comparison)."""

from __future__ import annotations

import math
from typing import Sequence

from .._stats import spread
from .runs import Run

__all__ = ["metric_summary", "compare_rows", "compare_table", "KEY_METRICS", "interval_summary", "method_pairs",
           "paired_differences", "best_counts"]

#: metrics shown first (in this order) when a run has them
KEY_METRICS = ("E_content", "E_style", "S_content", "S_style", "identity_content", "identity_style", "time_s",
               "ssim", "face_ssim", "mouth_ssim", "eyes_ssim", "grad_corr", "face_grad_corr", "colour_diff",
               "face_colour_diff", "mouth_slope", "mouth_r", "id_puppet", "id_frac", "flicker_ours", "fps")


def _order(names):
    key = [m for m in KEY_METRICS if m in names]
    return key + [m for m in names if m not in key]


def metric_summary(run: Run) -> list[dict]:
    """Per (method, metric): n, mean, std, 95 % CI of the mean, and the paper's value if any."""
    rows = []
    for method in run.methods:
        for metric in _order(run.metric_names):
            vals = run.values(method, metric)
            s = spread(vals)
            if s["n"] == 0:
                continue
            rows.append({"method": method, "metric": metric, **s,
                         "paper": run.paper.get(method, {}).get(metric)})
    return rows


def compare_rows(runs: Sequence[Run]) -> list[dict]:
    """One row per (method, metric) present in any run: each run's mean, std, n; and the
    difference of each later run's mean from the first run's."""
    table: dict[tuple[str, str], dict] = {}
    for i, run in enumerate(runs):
        for r in metric_summary(run):
            row = table.setdefault((r["method"], r["metric"]), {"method": r["method"], "metric": r["metric"],
                                                               "runs": [None] * len(runs)})
            row["runs"][i] = {k: r[k] for k in ("n", "mean", "std", "ci95_half")}
    out = []
    for row in table.values():
        base = row["runs"][0]
        row["delta"] = [None if (r is None or base is None) else r["mean"] - base["mean"] for r in row["runs"]]
        out.append(row)
    methods = []
    for run in runs:
        methods += [m for m in run.methods if m not in methods]
    metrics = _order(list(dict.fromkeys(r["metric"] for r in out)))
    out.sort(key=lambda r: (methods.index(r["method"]), metrics.index(r["metric"])))
    return out


def _fmt(v, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    a = abs(v)
    if a != 0 and (a >= 1e4 or a < 1e-3):
        return f"{v:.3g}"
    return f"{v:.{digits}g}" if a < 1 else f"{v:.{max(1, digits - len(str(int(a))))}f}"


def cell(r: dict | None) -> str:
    """``mean ± std (n)`` of a run's summary cell."""
    if r is None:
        return "–"
    if r["n"] < 2:
        return f"{_fmt(r['mean'])} (n=1)"
    return f"{_fmt(r['mean'])} ± {_fmt(r['std'], 2)} (n={r['n']})"


def compare_table(runs: Sequence[Run], *, markdown: bool = False) -> str:
    """The comparison as a text table (or Markdown): method, metric, then per run
    ``mean ± std (n)`` and, for later runs, the difference from the first."""
    rows = compare_rows(runs)
    head = ["method", "metric"] + [f"[{i + 1}] {r.name}" for i, r in enumerate(runs)] + \
           [f"Δ [{i + 1}]-[1]" for i in range(1, len(runs))]
    body = [[r["method"], r["metric"]] + [cell(c) for c in r["runs"]] + [_fmt(d) for d in r["delta"][1:]]
            for r in rows]
    legend = "\n".join(f"[{i + 1}] {r.path} ({r.kind}, {len(r.items)} items)" for i, r in enumerate(runs))
    if markdown:
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(b) + " |" for b in body]
        return legend + "\n\n" + "\n".join(lines) + "\n\nmean ± sample std over the items (n); Δ: difference of means.\n"
    widths = [max(len(str(x)) for x in col) for col in zip(head, *body)] if body else [len(h) for h in head]
    fmt = lambda cells: "  ".join(str(c).ljust(w) if i < 2 else str(c).rjust(w)  # noqa: E731
                                  for i, (c, w) in enumerate(zip(cells, widths)))
    lines = [fmt(head), "  ".join("-" * w for w in widths)] + [fmt(b) for b in body]
    return legend + "\n\n" + "\n".join(lines) + "\n\nmean ± sample std over the items (n); Δ: difference of means.\n"


def interval_summary(run: Run, metrics: Sequence[str] | None = None) -> list[dict]:
    """Per (method, metric): n, mean and the bootstrap 95 % interval of the mean inside the
    metric's range (none when n is below :data:`facetex._stats.MIN_N_INTERVAL`), and the
    paper's value if any."""
    from .._stats import bootstrap_mean
    from .metric_info import metric_info

    rows = []
    for method in run.methods:
        for metric in (metrics if metrics is not None else _order(run.metric_names)):
            b = bootstrap_mean(run.values(method, metric), bounds=metric_info(metric).bounds)
            if b["n"] == 0:
                continue
            rows.append({"method": method, "metric": metric, **b, "paper": run.paper.get(method, {}).get(metric)})
    return rows


def method_pairs(run: Run) -> list[tuple[str, str]]:
    """The (a, b) method pairs a report shows ``a − b`` of: every method against the baseline
    (the first of the run's method order: "no transfer", or the persona's static average),
    then the others against each other (later − earlier in the one method order)."""
    methods = run.methods
    base = run.method_order[0] if run.method_order and run.method_order[0] in methods else None
    others = [m for m in methods if m != base]
    out = [(m, base) for m in others] if base else []
    out += [(others[j], others[i]) for j in range(len(others) - 1, 0, -1) for i in range(j - 1, -1, -1)]
    return out


def paired_differences(run: Run, a: str, b: str, metric: str) -> dict:
    """``a − b`` of ``metric`` per item (the items both methods have), their mean with its
    bootstrap 95 % interval (see :func:`facetex._stats.bootstrap_mean`), and how many items
    each method wins where the metric has a direction (ties: equal values)."""
    from .._stats import bootstrap_mean
    from .metric_info import metric_info

    info = metric_info(metric)
    va, vb = run.values(a, metric), run.values(b, metric)
    diffs = [x - y for x, y in zip(va, vb) if math.isfinite(x) and math.isfinite(y)]
    res = {"a": a, "b": b, "metric": metric, "diffs": diffs,
           **bootstrap_mean(diffs, bounds=info.diff_bounds()), "wins_a": None, "wins_b": None, "ties": None}
    if info.better and diffs:
        sign = -1 if info.better == "lower" else 1
        res["wins_a"] = sum(1 for d in diffs if sign * d > 0)
        res["wins_b"] = sum(1 for d in diffs if sign * d < 0)
        res["ties"] = len(diffs) - res["wins_a"] - res["wins_b"]
    return res


def best_counts(run: Run, metric: str, methods: Sequence[str]) -> dict[str, int]:
    """How many items each of ``methods`` is the best of them on (a metric with a direction;
    an item where several share the best value counts for none)."""
    from .metric_info import metric_info

    info = metric_info(metric)
    counts = {m: 0 for m in methods}
    if not info.better or not methods:
        return counts
    cols = [run.values(m, metric) for m in methods]
    for vals in zip(*cols):
        finite = [(v if info.better == "higher" else -v, m) for v, m in zip(vals, methods) if math.isfinite(v)]
        if len(finite) < 2:
            continue
        top = max(v for v, _ in finite)
        best = [m for v, m in finite if v == top]
        if len(best) == 1:
            counts[best[0]] += 1
    return counts
