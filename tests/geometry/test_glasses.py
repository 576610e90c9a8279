"""Eyeglasses (facetex.geometry.glasses): a bridge line over the nose, weights by collection, a video's rims."""

import cv2
import numpy as np
import pytest

from _photos import draw_glasses
from facetex._resources import sample_path
from facetex.geometry.glasses import (glasses_bridge_score, glasses_weights, rim_mask, rim_response, rim_template,
                                      rims_present)
from facetex.landmarks import detect_face


@pytest.fixture(scope="module")
def face():
    img = cv2.imread(str(sample_path("frl_004_neutral.jpg")))[..., ::-1].copy()
    return img, detect_face(img.astype(np.float32) / 255).points68


def test_a_bridge_line_raises_the_score(face):
    img, p = face
    bare = glasses_bridge_score(img, p)
    worn = glasses_bridge_score(draw_glasses(img, p, arms=False), p)
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


def _video(img, n=6, seed=0):
    """n frames of a still face with the codec's noise (independent per frame)."""
    rng = np.random.default_rng(seed)
    return [np.clip(img + rng.normal(0, 4, img.shape), 0, 255).astype(np.uint8) for _ in range(n)]


def test_a_videos_drawn_glasses_are_found_and_kept_and_a_bare_face_has_none(face):
    img, p = face
    worn, bare = _video(draw_glasses(img, p)), _video(img)
    # no arms (or a frown's furrows between the eyes): not a pair of glasses
    assert not rims_present(rim_template([rim_response(f, p) for f in _video(draw_glasses(img, p, arms=False))]))
    t_worn = rim_template([rim_response(f, p) for f in worn])
    t_bare = rim_template([rim_response(f, p) for f in bare])
    assert t_worn.shape == (2, 96, 160)
    assert rims_present(t_worn) and not rims_present(t_bare)
    m = rim_mask(worn[0], p, t_worn)
    assert m.shape == img.shape[:2] and m.dtype == np.float32 and 0 <= m.min() and m.max() <= 1
    assert not rim_mask(bare[0], p, t_bare).any()
    # the rims beside and below the eyes and the bridge are kept (the eyes, brows and the nose below
    # the bridge are the puppet's: parts of the rims there are not)
    drawn = np.abs(draw_glasses(img, p).astype(int) - img.astype(int)).sum(-1) > 60
    iod = float(np.linalg.norm(p[36:42].mean(0) - p[42:48].mean(0)))
    yy, xx = np.mgrid[:img.shape[0], :img.shape[1]]
    below = drawn & (yy > p[36:48, 1].max() + 0.12 * iod) & (np.abs(xx - p[27, 0]) > 0.25 * iod)
    assert below.sum() > 50 and (m[below] > 0.5).mean() > 0.6
    # nothing on the skin away from them: the cheeks, the forehead
    grown = cv2.dilate(drawn.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    far = ~grown & (yy > p[36:48, 1].max() + 0.5 * iod) & (yy < p[33, 1])
    assert far.sum() > 500 and m[far].max() == 0.0
    # float frames in [0, 1] give the same mask
    np.testing.assert_allclose(rim_mask(worn[0].astype(np.float32) / 255, p, t_worn), m, atol=1e-4)


def test_glasses_are_found_in_a_dim_noisy_video(face):
    """A webcam in a dim room: 0.45 x the exposure and sensor noise of 6/255 per frame. The noise's
    thin lines would add up over the frames (a line response is never negative); the lines of the
    frames' mean luminance keep the rims and lose the noise."""
    img, p = face

    def dim(im, seed):
        rng = np.random.default_rng(seed)
        return [np.clip(im * 0.45 + 8 + rng.normal(0, 6, im.shape), 0, 255).astype(np.uint8) for _ in range(12)]

    assert rims_present(rim_template([rim_response(f, p) for f in dim(draw_glasses(img, p), 1)]))
    assert not rims_present(rim_template([rim_response(f, p) for f in dim(img, 2)]))
    assert not rims_present(rim_template([rim_response(f, p) for f in dim(draw_glasses(img, p, arms=False), 3)]))


def test_rims_without_landmarks_or_frames():
    img = np.zeros((40, 40, 3), np.uint8)
    assert rim_response(img, np.full((68, 2), np.nan)) is None
    assert rim_template([None, None]) is None and not rims_present(None)
    assert not rim_mask(img, np.full((68, 2), np.nan), np.ones((2, 96, 160), np.float32)).any()
