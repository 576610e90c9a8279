"""Eq. 3 weights and the Laplacian-pyramid blend (Tom Hanks Sec. 5), on hand-made arrays."""

import math

import numpy as np
import pytest

from facetex.persona.pyramid import (
    _level_scalars,
    blend_pyramids,
    collapse_pyramid,
    eq3_weights,
    expression_similarity,
    laplacian_pyramid,
    pyramid_levels,
)


def test_expression_similarity_hand_computed():
    target = np.zeros((49, 2))
    f = np.zeros((2, 49, 2))
    f[0, 0] = (3.0, 4.0)  # ||F^T - F^0||^2 = 25
    f[1, :2] = (1.0, 1.0)  # ||F^T - F^1||^2 = 4
    s = expression_similarity(target, f, sigma=5.0)
    assert s == pytest.approx([math.exp(-25 / 50), math.exp(-4 / 50)])
    # distances are scaled before the Gaussian: scale 2 is 4x the squared distance
    assert expression_similarity(target, f, sigma=5.0, scale=2.0)[0] == pytest.approx(math.exp(-100 / 50))


def test_eq3_weights_hand_computed():
    s = np.array([math.exp(-0.5), 0.1])
    L = np.array([[2.0, 1.0], [4.0, 0.5]])  # (n photos, pixels)
    # l = 2, beta = 2, tau = 1: uniform term 2^-2 = 0.25
    W = eq3_weights(s, L, 2, tau=1.0, beta=2.0, alpha=1.0)
    assert W[0] == pytest.approx([2 * (math.exp(-0.5) + 0.25), 1 * (math.exp(-0.5) + 0.25)])
    assert W[1] == pytest.approx([4 * 0.35, 0.5 * 0.35])
    # alpha = 2 squares the Laplacian response; tau scales the uniform term
    W2 = eq3_weights(s, L, 2, tau=4.0, beta=2.0, alpha=2.0)
    assert W2[1, 0] == pytest.approx(16 * (0.1 + 1.0))
    # paper values beta = 20: at l = 1 the uniform term is tau, at l = 3 negligible
    assert eq3_weights(s, L, 1)[1, 0] == pytest.approx(4 * 1.1)
    assert eq3_weights(s, L, 3)[1, 0] == pytest.approx(4 * (0.1 + 3.0**-20))
    # coarsest level l = 0: infinite uniform term -> expression-independent weights L^alpha
    assert np.allclose(eq3_weights(s, L, 0), L)


def test_level_scalars_uniform_dominates_coarse_levels():
    s = np.array([1.0, 1e-6, 0.0])
    assert np.allclose(_level_scalars(s, 0, 1.0, 20.0), 1.0)  # coarsest: uniform
    w1 = _level_scalars(s, 1, 1.0, 20.0)
    assert w1 == pytest.approx([1.0, 0.5, 0.5], rel=1e-5)  # (s + 1) / 2
    w5 = _level_scalars(s, 5, 1.0, 20.0)
    assert w5[0] == 1.0 and w5[2] < 1e-12  # finest levels: expression weights only


def test_pyramid_roundtrip_and_levels():
    rng = np.random.default_rng(0)
    img = rng.random((120, 96, 3)).astype(np.float32)
    p = pyramid_levels(img.shape, 8)
    assert p == 4  # 96 -> 48 -> 24 -> 12 (coarsest about 8 px)
    pyr = laplacian_pyramid(img, p)
    assert [b.shape[:2] for b in pyr] == [(120, 96), (60, 48), (30, 24), (15, 12)]
    assert np.allclose(collapse_pyramid(pyr), img, atol=1e-5)


def test_blend_of_identical_images_returns_the_image():
    rng = np.random.default_rng(1)
    img = rng.random((64, 48, 3)).astype(np.float32)
    pyr = laplacian_pyramid(img, 3)
    weights = [[rng.random(b.shape[:2]).astype(np.float32) + 0.1 for b in pyr] for _ in range(4)]
    out = blend_pyramids([pyr] * 4, weights)
    assert np.allclose(out, img, atol=1e-5)


def test_blend_weights_select_per_level():
    a = np.zeros((32, 32, 3), np.float32)
    b = np.ones((32, 32, 3), np.float32)
    pa, pb = laplacian_pyramid(a, 3), laplacian_pyramid(b, 3)
    # all weight on b at every level -> b; 3:1 everywhere -> 0.25
    wa = [np.zeros(x.shape[:2], np.float32) for x in pa]
    wb = [np.ones(x.shape[:2], np.float32) for x in pb]
    assert np.allclose(blend_pyramids([pa, pb], [wa, wb]), 1.0, atol=1e-5)
    wa3 = [3 * np.ones(x.shape[:2], np.float32) for x in pa]
    assert np.allclose(blend_pyramids([pa, pb], [wa3, wb]), 0.25, atol=1e-5)


def test_stack_arrays_share_one_map_without_overlapping():
    from facetex.persona._stack_parts import _small_page_arrays

    arrays = _small_page_arrays([(3, 5), (2, 7), (4, 1)])
    assert [a.shape for a in arrays] == [(3, 5), (2, 7), (4, 1)]
    for k, a in enumerate(arrays):
        a[...] = k + 1
    assert [(float(a.min()), float(a.max())) for a in arrays] == [(1, 1), (2, 2), (3, 3)]
    assert all(a.dtype == np.float32 and a.ctypes.data % 64 == 0 for a in arrays)
