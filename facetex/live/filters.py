"""Causal smoothing of the driver's per-frame motion: the One-Euro filter (Casiez, Roussel and Vogel,
"1 € Filter: A Simple Speed-based Low-pass Filter for Noisy Input in Interactive Systems", CHI 2012).

The offline puppetry smooths the whole clip with a zero-phase Savitzky-Golay filter
(:func:`facetex.puppet.driver.smooth_series`), which looks two frames ahead; a live stream has no
future frames. The One-Euro filter is an exponential smoother whose cut-off frequency rises with
the signal's speed: a still face is smoothed hard (no jitter), a fast motion (a mouth opening, a
head turn) passes with little lag. Per sample, with ``dt`` the time since the previous one:

    alpha(fc) = 1 / (1 + tau / dt),  tau = 1 / (2 pi fc)
    dx  = alpha(d_cutoff) (x - x_prev) / dt + (1 - alpha(d_cutoff)) dx_prev
    fc  = min_cutoff + beta |dx|
    out = alpha(fc) x + (1 - alpha(fc)) out_prev

The functions are pure (state in, state out); :class:`OneEuroFilter` keeps the state of one
series of arrays."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["OneEuroParams", "one_euro_alpha", "one_euro_step", "OneEuroFilter"]


@dataclass(frozen=True)
class OneEuroParams:
    """min_cutoff: cut-off frequency (Hz) of a still signal (lower: smoother, more lag when it
    starts moving); beta: how fast the cut-off rises with the speed (per unit of the signal per
    second; 0: a plain exponential smoother); d_cutoff: cut-off (Hz) of the speed estimate.
    ``min_cutoff=inf`` passes the signal unchanged."""

    min_cutoff: float = 1.0
    beta: float = 0.0
    d_cutoff: float = 1.0


def one_euro_alpha(cutoff, dt: float):
    """Smoothing factor in (0, 1] of an exponential smoother with cut-off ``cutoff`` (Hz, scalar or
    array) for samples ``dt`` seconds apart: 1 / (1 + tau / dt), tau = 1 / (2 pi cutoff)."""
    c = np.asarray(cutoff, np.float64)
    with np.errstate(divide="ignore"):
        tau = np.where(np.isinf(c), 0.0, 1.0 / (2.0 * math.pi * c))
    return 1.0 / (1.0 + tau / dt)


def one_euro_step(x, state, dt: float, params: OneEuroParams = OneEuroParams()):
    """(filtered x, new state) of one sample ``x`` (any shape) ``dt`` > 0 seconds after the previous.

    ``state``: None for the first sample (returned unchanged), else (previous output, previous
    speed estimate). The cut-off adapts per element."""
    x = np.asarray(x, np.float64)
    if state is None:
        return x.copy(), (x.copy(), np.zeros_like(x))
    prev, dprev = state
    dt = max(float(dt), 1e-6)
    ad = one_euro_alpha(params.d_cutoff, dt)
    dx = ad * (x - prev) / dt + (1.0 - ad) * dprev
    a = one_euro_alpha(params.min_cutoff + params.beta * np.abs(dx), dt)
    out = a * x + (1.0 - a) * prev
    return out, (out, dx)


class OneEuroFilter:
    """A One-Euro filter over a stream of same-shaped arrays (:func:`one_euro_step`).

    Parameters
    ----------
    params : OneEuroParams
        The filter's cut-offs and speed coefficient.

    Examples
    --------
    >>> f = OneEuroFilter(OneEuroParams(min_cutoff=1.0, beta=0.0))
    >>> float(f(0.0, 0.04)), round(float(f(1.0, 0.04)), 4)
    (0.0, 0.2008)
    """

    def __init__(self, params: OneEuroParams = OneEuroParams()):
        self.params = params
        self.state = None

    def __call__(self, x, dt: float) -> np.ndarray:
        """The filtered sample ``x``, ``dt`` seconds after the previous one."""
        out, self.state = one_euro_step(x, self.state, dt, self.params)
        return out

    def reset(self) -> None:
        """Forget the past (the next sample passes unchanged): after the face was lost."""
        self.state = None
