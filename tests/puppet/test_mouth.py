"""The puppet's mouth in face mode (facetex.puppet.mouth): the driver's interior in the puppet's white balance."""

from __future__ import annotations

import numpy as np
import pytest

from facetex.puppet.lighting import linear_to_srgb, srgb_to_linear
from facetex.puppet.mouth import interior_white_balance


def _lips68(cx=40.0, cy=30.0):
    """Outer lips 48-59 an ellipse 30 x 16 px round (cx, cy), inner lips 60-67 one 14 x 4 px."""
    p = np.zeros((68, 2))
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    p[48:60] = np.c_[cx - 15 * np.cos(t), cy - 8 * np.sin(t)]
    u = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    p[60:68] = np.c_[cx - 7 * np.cos(u), cy - 2 * np.sin(u)]
    return p


def _scene(lip_rgb):
    img = np.full((60, 80, 3), 0.5, np.float32)
    yy, xx = np.mgrid[0:60, 0:80]
    ring = (((xx - 40) / 15.0) ** 2 + ((yy - 30) / 8.0) ** 2 <= 1) & ~(((xx - 40) / 7.0) ** 2 + ((yy - 30) / 2.0) ** 2 <= 1)
    img[ring] = lip_rgb
    return img


def test_interior_takes_half_the_lips_colour_cast_keeping_its_lightness():
    d_lin, p_lin = np.float32([0.5, 0.2, 0.05]), np.float32([0.4, 0.2, 0.2])  # orange-lit lips, pink lips
    frame, image = _scene(linear_to_srgb(d_lin)), _scene(linear_to_srgb(p_lin))
    teeth = np.full((60, 80, 3), 0.0, np.float32)
    teeth[:] = linear_to_srgb(np.float32([0.6, 0.5, 0.3]))  # yellowish in the orange light
    out = interior_white_balance(teeth, frame, _lips68(), image, _lips68())
    g = np.sqrt(p_lin / d_lin)
    g = g / float(g @ np.float32([0.2126, 0.7152, 0.0722]))
    want = linear_to_srgb(np.float32([0.6, 0.5, 0.3]) * g)
    np.testing.assert_allclose(out[5, 5], want, atol=2e-3)
    # the cast only: the luminance ratio of the gain is 1, blue rises, red falls
    assert out[5, 5, 2] > teeth[5, 5, 2] and out[5, 5, 0] < teeth[5, 5, 0]
    assert float(srgb_to_linear(out[5, 5]) @ np.float32([0.2126, 0.7152, 0.0722])) == pytest.approx(
        float(np.float32([0.6, 0.5, 0.3]) * g @ np.float32([0.2126, 0.7152, 0.0722])), rel=1e-3)


def test_interior_white_balance_is_bounded_and_needs_both_lips():
    frame = _scene(linear_to_srgb(np.float32([0.9, 0.02, 0.01])))  # a red cast far past the bounds
    image = _scene(linear_to_srgb(np.float32([0.01, 0.02, 0.9])))
    grey = np.full((60, 80, 3), 0.5, np.float32)
    out = interior_white_balance(grey, frame, _lips68(), image, _lips68())
    ratio = srgb_to_linear(out[5, 5]) / srgb_to_linear(grey[5, 5])
    assert ratio.min() >= 0.5 - 1e-3 and ratio.max() <= 2.0 + 1e-3
    tiny = _lips68()
    tiny[48:68] = tiny[48:68].mean(axis=0)  # no lip pixels: unchanged
    np.testing.assert_array_equal(interior_white_balance(grey, frame, tiny, image, _lips68()), grey)
