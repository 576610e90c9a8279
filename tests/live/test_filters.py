"""The causal One-Euro filter against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from facetex.live.filters import OneEuroFilter, OneEuroParams, one_euro_alpha, one_euro_step


def test_alpha_by_hand():
    # tau = 1 / (2 pi 1 Hz) = 0.159155; dt = 0.04 s: alpha = 1 / (1 + 0.159155 / 0.04) = 0.200849
    assert one_euro_alpha(1.0, 0.04) == pytest.approx(0.200849, abs=1e-6)
    assert one_euro_alpha(float("inf"), 0.04) == 1.0


def test_two_steps_by_hand():
    p = OneEuroParams(min_cutoff=1.0, beta=0.1, d_cutoff=1.0)
    out, state = one_euro_step(2.0, None, 0.04, p)  # the first sample passes unchanged
    assert out == 2.0 and state[1] == 0.0
    out, state = one_euro_step(3.0, state, 0.04, p)
    a_d = 1 / (1 + 1 / (2 * math.pi) / 0.04)          # 0.200849 (d_cutoff 1 Hz)
    dx = a_d * (3.0 - 2.0) / 0.04                      # 5.02122 per second
    a = 1 / (1 + 1 / (2 * math.pi * (1.0 + 0.1 * dx)) / 0.04)  # cut-off 1.502 Hz: 0.274061
    assert state[1] == pytest.approx(dx)
    assert out == pytest.approx(a * 3.0 + (1 - a) * 2.0)
    assert out == pytest.approx(2.274061, abs=1e-6)


def test_constant_signal_is_unchanged_and_filter_is_causal():
    f = OneEuroFilter(OneEuroParams(min_cutoff=1.0, beta=0.5))
    for _ in range(5):
        np.testing.assert_allclose(f(np.array([1.5, -2.0]), 0.04), [1.5, -2.0])
    # a step: the output moves towards it monotonically, never past it, and never before it
    f.reset()
    outs = [float(f(x, 0.04)) for x in [0.0] * 3 + [1.0] * 10]
    assert outs[:3] == [0.0, 0.0, 0.0]
    assert all(b >= a for a, b in zip(outs, outs[1:])) and max(outs) <= 1.0


def test_speed_raises_the_cutoff():
    slow = OneEuroFilter(OneEuroParams(min_cutoff=1.0, beta=0.0))
    fast = OneEuroFilter(OneEuroParams(min_cutoff=1.0, beta=1.0))
    for f in (slow, fast):
        f(0.0, 0.04)
    assert fast(10.0, 0.04) > slow(10.0, 0.04)  # less lag for a fast change


def test_infinite_cutoff_passes_the_signal():
    f = OneEuroFilter(OneEuroParams(min_cutoff=float("inf")))
    xs = np.random.default_rng(0).normal(size=(6, 4))
    for x in xs:
        np.testing.assert_array_equal(f(x, 0.04), x)
