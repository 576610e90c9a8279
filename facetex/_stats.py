"""Summary statistics shared by the benches and the report (below both: neither imports the other
for them)."""

from __future__ import annotations

import math
from typing import Iterable

import numpy as np

__all__ = ["spread", "spread_text"]


def spread(values: Iterable) -> dict:
    """``n``, ``mean``, ``std`` (sample, ddof=1) and the 95 % confidence interval of the mean
    (Student t) of the finite values; NaN where undefined."""
    a = np.array([v for v in values if v is not None], dtype=np.float64)
    a = a[np.isfinite(a)]
    n = int(a.size)
    nan = float("nan")
    if n == 0:
        return {"n": 0, "mean": nan, "std": nan, "ci95": (nan, nan), "ci95_half": nan}
    mean = float(a.mean())
    if n == 1:
        return {"n": 1, "mean": mean, "std": nan, "ci95": (nan, nan), "ci95_half": nan}
    from scipy import stats

    std = float(a.std(ddof=1))
    half = float(stats.t.ppf(0.975, n - 1) * std / math.sqrt(n))
    return {"n": n, "mean": mean, "std": std, "ci95": (mean - half, mean + half), "ci95_half": half}


def spread_text(values: Iterable, fmt: str = ".3f") -> str:
    """``"mean ± std [lo, hi]"`` (std: sample standard deviation; brackets: 95 % CI of the mean)."""
    s = spread(values)
    if s["n"] == 0:
        return "–"
    if s["n"] == 1:
        return f"{s['mean']:{fmt}}"
    return f"{s['mean']:{fmt}} ± {s['std']:{fmt}} [{s['ci95'][0]:{fmt}}, {s['ci95'][1]:{fmt}}]"
