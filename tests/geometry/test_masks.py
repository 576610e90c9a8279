import cv2
import numpy as np
import pytest

from facetex._resources import sample_path
from facetex.errors import BadInputError
from facetex.geometry.masks import (
    REF_FACE_WIDTH,
    face_mask,
    face_outline,
    face_width,
    facial_prior_mask,
    feature_mask,
    forehead_points,
    nose_mask,
    prior_mask,
)
from facetex.landmarks import detect_face


@pytest.fixture(scope="module")
def face():
    img = cv2.imread(str(sample_path("frl_004_neutral.jpg")))[..., ::-1]
    return detect_face(img).points68, img.shape[:2]


def _at(mask, pt):
    return float(mask[int(round(pt[1])), int(round(pt[0]))])


def test_shapes_dtypes_ranges(face):
    p, shape = face
    for m in (facial_prior_mask(p, shape), face_mask(p, shape), prior_mask(p, shape)):
        assert m.shape == shape and m.dtype == np.float32
        assert m.min() >= 0.0 and m.max() <= 1.0
    fp = facial_prior_mask(p, shape)
    assert fp.min() == pytest.approx(0.0, abs=1e-6) and fp.max() == pytest.approx(1.0, abs=1e-6)


def test_meso_structures_weigh_less_than_cheeks(face):
    p, shape = face
    fp = facial_prior_mask(p, shape)
    eye = p[36:42].mean(0)
    mouth = p[[48, 54, 62, 66]].mean(0)
    cheek = (p[2] + p[31] + p[48]) / 3  # between the jaw, the nostril and the mouth corner
    for m in (fp, prior_mask(p, shape)):
        assert _at(m, eye) < _at(m, cheek) - 0.2
        assert _at(m, mouth) < _at(m, cheek) - 0.2
    # far from all contours the prior is 1 (nothing drawn there)
    assert _at(fp, (5, 5)) == pytest.approx(1.0)


def test_face_mask_background_forehead_and_hair(face):
    p, shape = face
    m = face_mask(p, shape)
    brow = p[17:27].mean(0)
    up = brow - p[33]  # towards the top of the head
    forehead = brow + 0.4 * up
    assert _at(m, forehead) > 0.95
    assert _at(m, p[30]) > 0.95  # nose tip
    for bg in [(5, 5), (395, 5), (5, 200), (395, 200)]:
        assert _at(m, bg) < 0.01
    # far above the forehead arc (hair / background) is excluded
    top = forehead_points(p).min(axis=0)[1]
    assert _at(m, (brow[0], top - 0.15 * face_width(p))) < 0.05
    # the prior mask is zero outside the face as well
    assert _at(prior_mask(p, shape), (5, 5)) < 0.01


def test_forehead_arc_above_brows_and_outline_closed(face):
    p, _ = face
    f = forehead_points(p)
    assert f[:, 1].min() < p[17:27, 1].min() - 10
    o = face_outline(p)
    assert o.shape == (17 + len(f), 2)
    # outline area larger than the jaw polygon alone
    assert cv2.contourArea(o.astype(np.float32)) > 1.2 * cv2.contourArea(p[:17].astype(np.float32))


def test_masks_agree_across_resolutions(face):
    p, (H, W) = face
    s = 2.5
    p2 = (p + 0.5) * s - 0.5
    shape2 = (int(H * s), int(W * s))
    for fn in (facial_prior_mask, face_mask, prior_mask):
        lo = fn(p, (H, W))
        hi = cv2.resize(fn(p2, shape2), (W, H), interpolation=cv2.INTER_AREA)
        assert np.abs(lo - hi).mean() < 0.02
        assert np.percentile(np.abs(lo - hi), 99) < 0.1


def test_line_width_scales_with_face_size(face):
    p, shape = face
    # at the reference face width the drawn contour is line_px wide: check the dark band
    # of an unblurred-equivalent (ksize 1) prior across the chin
    s = REF_FACE_WIDTH / face_width(p)
    q = p * s
    shape_s = (int(shape[0] * s), int(shape[1] * s))
    fp = facial_prior_mask(q, shape_s, ksize=1, sigma=0.01)
    chin = q[8]
    col = fp[:, int(round(chin[0]))]
    ys = np.nonzero(col[int(chin[1]) - 60 : int(chin[1]) + 60] < 0.5)[0]
    assert 36 <= len(ys) <= 44


def test_bad_points():
    with pytest.raises(BadInputError):
        face_mask(np.zeros((5, 2)), (10, 10))
    with pytest.raises(BadInputError):
        facial_prior_mask(np.zeros((68, 2)), (0, 10))


def test_nose_mask_is_the_lower_nose_grown_by_the_eye_distance():
    """Hull of points 29-35 grown by 0.08 x the outer eye-corner distance (50 px: 4 px); the
    bridge's top (27-28, where glasses sit) is left out."""
    p = np.zeros((68, 2))
    p[36], p[45] = (20, 30), (70, 30)
    p[27:36] = [(45, 20), (45, 30), (45, 40), (45, 48), (38, 55), (41, 56), (45, 57), (49, 56), (52, 55)]
    m = nose_mask(p, (80, 90))
    assert m[48, 45] and m[45, 41]  # inside the hull
    assert m[60, 45] and not m[63, 45]  # 3 px below the tip in, 6 px out (grown 4)
    assert m[55, 35] and not m[55, 31]  # beside the left ala (x 38): 3 px in, 7 px out
    assert not m[30, 45] and not m[22, 45]  # the bridge's top
    assert nose_mask(p, (80, 90), grow=0.2)[63, 45]  # grown 10 px


def test_feature_mask_parts_make_up_the_whole(face):
    p, shape = face
    whole = feature_mask(p, shape)
    parts = {k: feature_mask(p, shape, parts=(k,)) for k in ("eyes", "brows", "lips")}
    np.testing.assert_array_equal(parts["eyes"] | parts["brows"] | parts["lips"], whole)
    assert all(m.any() for m in parts.values())
    assert _at(parts["brows"], p[19] + [0, 2]) and not _at(parts["brows"], p[62])
    assert _at(parts["lips"], p[62]) and not _at(parts["lips"], p[19] + [0, 2])
    assert not feature_mask(p, shape, parts=()).any()
