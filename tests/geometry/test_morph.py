
import cv2
import numpy as np
import pytest

from facetex._resources import sample_path
from facetex.errors import BadInputError
from facetex.geometry.style_align import AlignResult, align_style_to_content
from facetex.geometry.morph import beier_neely_lines_map, beier_neely_map, beier_neely_warp, invert_map_points, morph_points, morph_segments, piecewise_affine_map, piecewise_affine_warp, remap, sample_map
from facetex.landmarks import detect_face


def _load(name):
    return cv2.imread(str(sample_path(name)))[..., ::-1].astype(np.float32) / 255.0


@pytest.fixture(scope="module")
def pair():
    """style frl_005_neutral, content frl_004_neutral (400 px) with their landmarks."""
    style, content = _load("frl_005_neutral.jpg"), _load("frl_004_neutral.jpg")
    return style, content, detect_face(style).points68, detect_face(content).points68


def _grid(H, W):
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    return np.stack([xx, yy], axis=-1)


# --- Beier-Neely on hand-made lines ---------------------------------------------


def test_single_line_pair_is_its_similarity():
    # destination line (10,10)-(30,10); source line rotated 90 deg and doubled about (50,50)
    dst = np.array([[[10.0, 10.0], [30.0, 10.0]]])
    src = np.array([[[50.0, 50.0], [50.0, 90.0]]])
    m = beier_neely_lines_map(src, dst, (40, 60), a=1.0)
    # X = (20, 20): u = 0.5, v = (X-P).perp(d)/|d| = 10 -> X' = P' + 0.5 (0, 40) + 10 * (-1, 0) * 2 / 2
    assert np.allclose(m[20, 20], [40.0, 70.0], atol=1e-3)
    assert np.allclose(m[10, 10], [50.0, 50.0], atol=1e-3)  # P -> P'
    assert np.allclose(m[10, 30], [50.0, 90.0], atol=1e-3)  # Q -> Q'


def test_two_lines_hand_weighted():
    # two horizontal lines translated by (+4, 0) and (0, +6); point midway at distance 5 from both
    dst = np.array([[[0.0, 0.0], [10.0, 0.0]], [[0.0, 10.0], [10.0, 10.0]]])
    src = dst + np.array([[[4.0, 0.0]], [[0.0, 6.0]]])
    a, b, p = 1.0, 2.0, 0.5
    m = beier_neely_lines_map(src, dst, (12, 12), a=a, b=b, p=p)
    # at (5, 5): equal weights -> mean displacement (2, 3)
    assert np.allclose(m[5, 5], [7.0, 8.0], atol=1e-4)
    # at (5, 2): dists 2 and 8, w = (10^0.5 / (1 + d))^2
    w1, w2 = (10**0.5 / 3) ** 2, (10**0.5 / 9) ** 2
    expect = np.array([5.0, 2.0]) + (w1 * np.array([4, 0]) + w2 * np.array([0, 6])) / (w1 + w2)
    assert np.allclose(m[2, 5], expect, atol=1e-4)


def test_identity_when_points_do_not_move(pair):
    _, content, _, cp = pair
    m = beier_neely_map(cp, cp, content.shape[:2])
    assert np.abs(m - _grid(*content.shape[:2])).max() < 1e-3
    m = piecewise_affine_map(cp, cp, content.shape[:2])
    assert np.abs(m - _grid(*content.shape[:2])).max() < 1e-3


def test_segments_cover_face_and_frame():
    seg = morph_segments()
    pts = morph_points(np.random.default_rng(0).uniform(100, 300, (68, 2)), (400, 400))
    used = set(seg.ravel())
    assert used == set(range(len(pts)))  # every landmark, forehead and frame point is an end point


# --- landmark accuracy on real faces -------------------------------------------------


@pytest.mark.parametrize("fn", [beier_neely_map, piecewise_affine_map])
def test_morph_moves_landmarks_onto_content(pair, fn):
    style, content, sp, cp = pair
    m = fn(sp, cp, content.shape[:2])
    assert np.linalg.norm(sample_map(m, cp) - sp, axis=1).max() < 0.5
    moved = invert_map_points(m, sp, init=cp + 5.0)
    assert np.linalg.norm(moved - cp, axis=1).max() < 1.5
    # sanity: the unwarped style is far off
    assert np.linalg.norm(sp - cp, axis=1).mean() > 5


def test_beier_neely_coarse_matches_exact(pair):
    _, _, sp, cp = pair
    sp, cp = sp * 0.5, cp * 0.5  # 200 x 200 keeps the exact evaluation quick
    exact = beier_neely_map(sp, cp, (200, 200), step=1)
    coarse = beier_neely_map(sp, cp, (200, 200), step=2)
    assert np.abs(exact - coarse).max() < 0.15


def test_warps_keep_background_and_match_maps(pair):
    style, content, sp, cp = pair
    for warp, fn in ((beier_neely_warp, beier_neely_map), (piecewise_affine_warp, piecewise_affine_map)):
        out = warp(style, sp, cp)
        assert out.shape == style.shape and out.dtype == np.float32
        m = fn(sp, cp, content.shape[:2])
        np.testing.assert_allclose(out, remap(style, m), atol=1e-6)
        # the frame is held: image corners sample themselves
        for y, x in [(0, 0), (0, 399), (399, 0), (399, 399)]:
            assert np.allclose(m[y, x], [x, y], atol=0.5)


@pytest.mark.parametrize(
    "method,refine",
    [("beier-neely", "sift-flow"), ("piecewise-affine", "optical-flow"), ("beier-neely", None)],
)
def test_align_style_to_content(pair, method, refine):
    style, content, sp, cp = pair
    r = align_style_to_content(style, content, style_points=sp, content_points=cp, method=method, refine=refine)
    assert isinstance(r, AlignResult)
    assert r.image.shape == content.shape and r.map_xy.shape == content.shape[:2] + (2,)
    # the morph pins the landmarks; the (smoothed, capped) flow refinement may move them a little
    assert np.linalg.norm(r.points - cp, axis=1).max() < (1.5 if refine is None else 2.0)
    redetected = detect_face(r.image).points68
    assert np.linalg.norm(redetected - cp, axis=1).mean() < 3.0
    # the map warps other data the same way
    np.testing.assert_allclose(remap(style, r.map_xy), r.image, atol=1e-6)
    assert {"morph", "refine", "warp"} <= set(r.timings)


def test_align_refinement_stays_in_face_and_is_bounded(pair):
    style, content, sp, cp = pair
    base = align_style_to_content(style, content, style_points=sp, content_points=cp, refine=None)
    ref = align_style_to_content(style, content, style_points=sp, content_points=cp, refine="optical-flow")
    d = np.linalg.norm(ref.map_xy - base.map_xy, axis=2)
    assert d[:40].max() < 1e-3 and d[:, :40].max() < 1e-3  # background untouched
    assert d.max() > 0.05  # but it did something
    assert d.max() < 0.05 * np.linalg.norm(cp[16] - cp[0]) * 2  # capped (x morph's local stretch)


def test_align_detects_landmarks_when_missing(pair):
    style, content, sp, cp = pair
    r = align_style_to_content(style, content, refine=None)
    assert np.linalg.norm(r.points - cp, axis=1).max() < 1.5


def test_bad_options(pair):
    style, content, sp, cp = pair
    with pytest.raises(BadInputError):
        align_style_to_content(style, content, style_points=sp, content_points=cp, method="tps")
    with pytest.raises(BadInputError):
        align_style_to_content(style, content, style_points=sp, content_points=cp, refine="magic")
    with pytest.raises(BadInputError):
        beier_neely_map(sp[:10], cp, (100, 100))


# --- crops, similarity frame, folds ---------------------------------------------

from facetex.geometry.morph import jacobian_determinant, similarity_frame, similarity_transform, unfold_map  # noqa: E402


def test_similarity_transform_recovers_a_known_similarity():
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 100, (20, 2))
    th, s, t = 0.3, 1.7, np.array([5.0, -3.0])
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    b = s * a @ R.T + t
    T = similarity_transform(a, b)
    assert np.allclose(T[:, :2], s * R, atol=1e-9) and np.allclose(T[:, 2], t, atol=1e-7)


def test_jacobian_determinant_of_an_affine_map():
    yy, xx = np.mgrid[0:20, 0:30].astype(np.float32)
    m = np.stack([2.0 * xx + 0.5 * yy + 3, -0.5 * xx + 1.5 * yy], -1)  # det = 2*1.5 + 0.25 = 3.25
    assert np.allclose(jacobian_determinant(m), 3.25, atol=1e-5)
    flipped = np.stack([-xx, yy], -1)
    assert (jacobian_determinant(flipped) < 0).all()


def test_unfold_map_removes_a_fold_and_keeps_the_rest():
    yy, xx = np.mgrid[0:80, 0:80].astype(np.float32)
    ident = np.stack([xx, yy], -1)
    bump = np.zeros_like(ident)
    bump[..., 0] = 12.0 * np.exp(-((xx - 40) ** 2 + (yy - 40) ** 2) / (2 * 3.0**2))  # slope > 1: folds
    assert (jacobian_determinant(ident + bump) <= 0).any()
    out = unfold_map(lambda a: ident + a[..., None] * bump, (80, 80))
    assert (jacobian_determinant(out) > 0).all()
    far = (np.hypot(xx - 40, yy - 40) > 35)
    assert np.allclose(out[far], (ident + bump)[far], atol=1e-3)


def test_prewarp_on_a_crop_equals_the_full_image_prewarp_cropped(pair):
    """The crop's frame must not be pinned to the style image's frame (issue 11, cause 1)."""
    style, content, sp, cp = pair
    full = align_style_to_content(style, content, style_points=sp, content_points=cp, refine=None)
    x0, y0, x1, y1 = 90, 60, 320, 360
    crop = align_style_to_content(style, content[y0:y1, x0:x1], style_points=sp, content_points=cp - [x0, y0],
                                  refine=None)
    inner = (slice(40, -40), slice(40, -40))  # away from the crop's own frame points
    d = np.linalg.norm(crop.map_xy[inner] - full.map_xy[y0:y1, x0:x1][inner], axis=2)
    assert np.median(d) < 1.0 and np.percentile(d, 95) < 3.0
    # and the style keeps its scale: no squeezing of the whole photo into the crop
    T = similarity_transform(cp, sp)
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float64)
    sim = np.stack([T[0, 0] * xx + T[0, 1] * yy + T[0, 2], T[1, 0] * xx + T[1, 1] * yy + T[1, 2]], -1)
    assert np.median(np.linalg.norm(crop.map_xy - sim, axis=2)) < 0.05 * 130


def test_prewarp_is_fold_free_on_the_face(pair):
    style, content, sp, cp = pair
    r = align_style_to_content(style, content, style_points=sp, content_points=cp, refine="optical-flow")
    assert r.folds == 0
    from facetex.geometry.masks import face_mask

    assert (jacobian_determinant(r.map_xy)[face_mask(cp, content.shape[:2]) > 0.5] > 0).all()


def test_similarity_frame_maps_the_crop_frame_through_the_landmark_similarity(pair):
    style, content, sp, cp = pair
    fr = similarity_frame(sp, cp, (100, 200))
    T = similarity_transform(cp, sp)
    assert np.allclose(fr[0], T[:, 2]) and np.allclose(fr[4], T @ [199.0, 99.0, 1.0])
