"""Sideways gaze (facetex.geometry.gaze): the balance of the eyes' whites, weights by collection."""

import numpy as np
import pytest

from facetex.geometry.gaze import gaze_asymmetry, gaze_weights


def _eyes(iris_shift=0.0, h=60, w=100):
    """A grey face with two white eyes 24 px wide whose dark irises (8 px) sit ``iris_shift`` x the
    eye width right of the eye's centre, and its iBUG-68 points (eyes only; the rest far away)."""
    img = np.full((h, w, 3), 0.6, np.float32)
    p = np.full((68, 2), 5.0)
    for k, cx in ((36, 30.0), (42, 70.0)):
        x0, x1, y0, y1 = cx - 12, cx + 12, 24.0, 36.0
        # outline 36-41: outer corner, two upper-lid points, inner corner, two lower-lid points
        p[k:k + 6] = [(x0, 30), (cx - 4, y0), (cx + 4, y0), (x1, 30), (cx + 4, y1), (cx - 4, y1)]
        img[int(y0):int(y1) + 1, int(x0):int(x1) + 1] = 0.95
        ic = cx + iris_shift * 24
        img[int(y0):int(y1) + 1, int(ic - 4):int(ic + 4)] = 0.15
    return img, p


def test_centred_irises_score_zero_and_sideways_ones_the_sign_of_the_whites():
    img, p = _eyes(0.0)
    assert gaze_asymmetry(img, p) == pytest.approx(0.0, abs=0.05)
    right = gaze_asymmetry(*_eyes(0.2))  # irises to the image's right: white shows on the left
    left = gaze_asymmetry(*_eyes(-0.2))
    assert right > 0.3 and left < -0.3
    assert right == pytest.approx(-left, abs=0.12)  # (the irises are placed to the pixel)
    # uint8 input gives the same score
    u8, p8 = _eyes(0.2)
    assert gaze_asymmetry((u8 * 255).round().astype(np.uint8), p8) == pytest.approx(right, abs=0.02)


def test_shading_of_the_inner_corners_cancels_between_the_eyes():
    img, p = _eyes(0.0)
    img[:, 40:60] *= 0.8  # the nose side darker: the inner corners of both eyes
    img[:, 38:42] *= 0.9
    assert abs(gaze_asymmetry(img, p)) < 0.05


def test_gaze_is_nan_off_the_image():
    img, p = _eyes(0.0)
    q = p.copy()
    q[36:48, 0] -= 40
    assert np.isnan(gaze_asymmetry(img, q))
    assert np.isnan(gaze_asymmetry(img, np.zeros((5, 2))))


def test_gaze_weights_fall_with_the_distance_from_the_collections_median():
    s = np.array([0.1, 0.1, 0.1, 0.4, -0.5, np.nan])
    w = gaze_weights(s, 0.3)
    np.testing.assert_allclose(w[:3], 1.0)
    assert w[3] == pytest.approx(np.exp(-1.0))  # hand-computed: ((0.4 - 0.1) / 0.3)^2 = 1
    assert w[4] == pytest.approx(np.exp(-4.0))
    assert w[5] == 1.0
    np.testing.assert_array_equal(gaze_weights(s, 0.0), 1.0)
