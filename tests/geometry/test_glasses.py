"""Eyeglasses score (facetex.geometry.glasses): a bridge line over the nose, weights by collection."""

import cv2
import numpy as np
import pytest

from facetex._resources import sample_path
from facetex.geometry.glasses import glasses_bridge_score, glasses_weights
from facetex.landmarks import detect_face


@pytest.fixture(scope="module")
def face():
    img = cv2.imread(str(sample_path("frl_004_neutral.jpg")))[..., ::-1].copy()
    return img, detect_face(img.astype(np.float32) / 255).points68


def _with_glasses(img, p):
    """The face with a pair of glasses drawn: two dark rims round the eyes and the bridge."""
    out = img.copy()
    iod = float(np.linalg.norm(p[36:42].mean(0) - p[42:48].mean(0)))
    t = max(2, int(round(0.04 * iod)))
    for eye in (p[36:42], p[42:48]):
        c = eye.mean(0)
        cv2.ellipse(out, tuple(int(v) for v in c), (int(0.42 * iod), int(0.28 * iod)), 0, 0, 360, (30, 30, 30), t)
    y = int(round((p[39, 1] + p[42, 1]) / 2 - 0.1 * iod))
    cv2.line(out, (int(p[39, 0]), y), (int(p[42, 0]), y), (30, 30, 30), t)
    return out


def test_a_bridge_line_raises_the_score(face):
    img, p = face
    bare = glasses_bridge_score(img, p)
    worn = glasses_bridge_score(_with_glasses(img, p), p)
    assert np.isfinite(bare) and worn > 2 * bare
    # float input in [0, 1] gives the same score as uint8
    assert glasses_bridge_score(img.astype(np.float32) / 255, p) == pytest.approx(bare, rel=1e-5)


def test_score_is_nan_without_a_box():
    img = np.zeros((40, 40, 3), np.uint8)
    p = np.full((68, 2), np.nan)
    assert np.isnan(glasses_bridge_score(img, p))
    p = np.zeros((68, 2))  # every point at the corner: the box is off the image
    assert np.isnan(glasses_bridge_score(img, p))


def test_weights_by_the_collections_median():
    # median 1, level 1.5: 3 is 2x the level -> 2 ** -4; 1.2 is below the level -> 1; NaN -> 1
    w = glasses_weights([1.0, 1.0, 1.2, 3.0, np.nan, 0.5], level=1.5, power=4.0)
    assert w == pytest.approx([1, 1, 1, 2.0 ** -4, 1, 1])
    assert glasses_weights([1.0, 9.0], power=4.0) == pytest.approx([1, 1])  # too few photos to judge
    assert glasses_weights([1.0, 1.0, 3.0], power=0) == pytest.approx([1, 1, 1])
