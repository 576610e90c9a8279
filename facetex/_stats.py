"""Summary statistics shared by the benches and the report (below both: neither imports the other
for them)."""

from __future__ import annotations

import math
from typing import Iterable

import numpy as np

__all__ = ["finite_values", "spread", "spread_text", "bootstrap_mean", "MIN_N_INTERVAL"]

#: fewer items than this: no interval (a bootstrap of 2-4 values has a handful of distinct means and
#: says nothing about the spread)
MIN_N_INTERVAL = 5
#: Above this many values an interval is the percentile one, from resamples drawn in batches, at
#: most :data:`BIG_RESAMPLED` values in all: scipy otherwise holds n_resamples x n values at once
#: and BCa's jackknife n x n (7 GB at n = 30 000, issue 23); at such n BCa and percentile agree.
BIG_N = 2000
BIG_RESAMPLED = 20_000_000


def finite_values(values) -> np.ndarray:
    """float64 array of the finite values (None, NaN and infinities left out)."""
    a = np.array([v for v in values if v is not None], dtype=np.float64)
    return a[np.isfinite(a)]


def spread(values: Iterable) -> dict:
    """``n``, ``mean``, ``std`` (sample, ddof=1) and the 95 % confidence interval of the mean
    (Student t) of the finite values; NaN where undefined."""
    a = finite_values(values)
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


def bootstrap_mean(values: Iterable, *, bounds: tuple[float, float] = (-math.inf, math.inf),
                   confidence: float = 0.95, min_n: int = MIN_N_INTERVAL, n_resamples: int = 9999,
                   seed: int = 0) -> dict:
    """The mean of the finite ``values`` and its bootstrap confidence interval, inside ``bounds``.

    Parameters
    ----------
    values : iterable of float
        One value per item (pair, target, run); None and NaN are left out.
    bounds : (float, float)
        The metric's range (e.g. ``(0, inf)`` for a landmark error, ``(-1, 1)`` for a
        correlation); the interval never leaves it.
    confidence : float
        Confidence level of the interval.
    min_n : int
        Fewer finite values than this: no interval (``lo`` and ``hi`` are NaN).
    n_resamples : int
        Bootstrap resamples.
    seed : int
        Seed of the resampling: the same values give the same interval.

    Returns
    -------
    dict
        ``n``, ``mean``, ``lo``, ``hi`` (NaN when undefined) and ``interval`` (the
        :func:`scipy.stats.bootstrap` method used, or None without an interval).

    Notes
    -----
    :func:`scipy.stats.bootstrap` with the BCa interval (percentile when BCa is undefined,
    e.g. every resample has the same mean). Both are quantiles of resampled means, so they
    lie inside the values' own range, unlike a Student-t interval, which with n = 2 reaches
    far outside any metric's range; the clip to ``bounds`` only guards the last bit. Above
    :data:`BIG_N` values: the percentile interval, resampled in batches (bounded memory).

    Examples
    --------
    >>> r = bootstrap_mean([0, 0, 0, 0, 0, 0, 0, 0, 0, 10], bounds=(0, math.inf))
    >>> r["mean"], r["lo"] >= 0, r["hi"] <= 10
    (1.0, True, True)
    >>> math.isnan(bootstrap_mean([1.0, 2.0])["lo"])
    True
    """
    a = finite_values(values)
    n = int(a.size)
    lo_b, hi_b = float(bounds[0]), float(bounds[1])
    nan = float("nan")
    if n == 0:
        return {"n": 0, "mean": nan, "lo": nan, "hi": nan, "interval": None}
    mean = float(min(max(a.mean(), lo_b), hi_b))
    if n < min_n:
        return {"n": n, "mean": mean, "lo": nan, "hi": nan, "interval": None}
    if np.ptp(a) == 0:  # every resample has this mean: the interval is the point
        return {"n": n, "mean": mean, "lo": mean, "hi": mean, "interval": "constant"}
    import warnings

    from scipy import stats

    lo = hi = nan
    used = None
    methods, batch = ("BCa", "percentile"), None
    if n > BIG_N:
        methods, batch = ("percentile",), max(1, 4_000_000 // n)
        n_resamples = min(n_resamples, max(999, BIG_RESAMPLED // n))
    for method in methods:
        with warnings.catch_warnings():  # BCa warns (and gives NaN) for degenerate resamples: then percentile
            warnings.simplefilter("ignore")
            res = stats.bootstrap((a,), np.mean, confidence_level=confidence, n_resamples=n_resamples,
                                  method=method, rng=np.random.default_rng(seed), batch=batch)
        lo, hi = float(res.confidence_interval.low), float(res.confidence_interval.high)
        if math.isfinite(lo) and math.isfinite(hi):
            used = method
            break
    if used is None:
        return {"n": n, "mean": mean, "lo": nan, "hi": nan, "interval": None}
    return {"n": n, "mean": mean, "lo": min(max(lo, lo_b), mean), "hi": max(min(hi, hi_b), mean), "interval": used}
