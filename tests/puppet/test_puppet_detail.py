"""facetex.puppet.detail: the frame's grain on a puppet that its own bounded sharpening left smoother."""

from __future__ import annotations

import numpy as np

from facetex.puppet.detail import GRAIN_CLIP, match_grain


def _checker(h=40, w=48) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w]
    return np.where((yy + xx) % 2 == 0, 1.0, -1.0).astype(np.float32)[..., None] * np.ones(3, np.float32)


def test_match_grain_adds_the_frames_fine_band_by_the_hand_computed_amount():
    """Checkerboards c = +-1: the frame 0.5 + 0.1 c, the puppet 0.5 + 0.04 c. The frame's band
    (x minus its 4 neighbours' mean) is 0.2 c, under the clip (2.5 x 1.4826 x 0.2); the
    4-neighbour Laplacians are -8 x 0.04 c and -8 x 0.2 c, so Var(lap(src + a band)) =
    64 (0.04 + 0.2 a)^2 equals the frame's 64 x 0.1^2 at a = 0.3 (0.306: the image border's
    reflected pixels break the pattern there), and inside, the result is the frame's checkerboard."""
    c = _checker()
    ref, src = 0.5 + 0.1 * c, 0.5 + 0.04 * c
    skin = np.ones(c.shape[:2], bool)
    out, a = match_grain(src, ref, skin)
    assert abs(a - 0.3) < 0.01
    np.testing.assert_allclose(out[2:-2, 2:-2], 0.5 + (0.04 + 0.2 * a) * c[2:-2, 2:-2], atol=1e-5)
    np.testing.assert_allclose(out[2:-2, 2:-2], ref[2:-2, 2:-2], atol=0.002)
    capped, a1 = match_grain(src, ref, skin, max_amount=0.1)  # bounded
    assert a1 == 0.1
    np.testing.assert_allclose(capped[2:-2, 2:-2], 0.5 + 0.06 * c[2:-2, 2:-2], atol=1e-5)


def test_match_grain_leaves_a_puppet_as_detailed_as_the_frame_alone():
    c = _checker()
    src, ref = 0.5 + 0.1 * c, 0.5 + 0.05 * c
    out, a = match_grain(src, ref, np.ones(c.shape[:2], bool))
    assert a == 0.0 and np.array_equal(out, src)
    out, a = match_grain(src, 0.5 + 0.2 * c, np.zeros(c.shape[:2], bool))  # no skin: nothing
    assert a == 0.0 and np.array_equal(out, src)


def test_match_grain_clips_the_frames_strong_lines_and_stays_on_the_skin():
    """A dark 1 px line (a glasses rim) across the frame's grainy skin comes through clipped to
    GRAIN_CLIP robust standard deviations of the grain, not at its own depth; pixels more than 4 px
    (the feather's reach) from the skin are untouched."""
    rng = np.random.default_rng(0)
    h, w = 60, 64
    grain = rng.normal(0, 0.02, (h, w, 1)).astype(np.float32) * np.ones(3, np.float32)
    ref = 0.6 + grain
    ref[30] = 0.1  # the rim
    src = np.full((h, w, 3), 0.6, np.float32)
    skin = np.zeros((h, w), bool)
    skin[:, :40] = True
    out, a = match_grain(src, ref, skin)
    assert 0 < a <= 1
    band = ref - 0.25 * (np.roll(ref, 1, 0) + np.roll(ref, -1, 0) + np.roll(ref, 1, 1) + np.roll(ref, -1, 1))
    sd = 1.4826 * np.median(np.abs(band[5:25, 5:35, 0]))
    assert np.abs(out[30, 5:35] - 0.6).max() <= a * GRAIN_CLIP * sd * 1.1  # the rim: clipped
    assert np.abs(out[30, 5:35] - 0.6).max() < 0.2 * 0.5  # far below its 0.5 depth
    np.testing.assert_array_equal(out[:, 45:], src[:, 45:])
    assert np.std(out[5:25, 5:35] - src[5:25, 5:35]) > 0.01  # grain where the skin is
