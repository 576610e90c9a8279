import json

import cv2
import numpy as np
import pytest

from facetex import metrics
from facetex._resources import sample_path
from facetex.errors import BadInputError


def _grid_points68(scale=1.0, offset=(0.0, 0.0)):
    # a plausible frontal 68-point layout is not needed for E; any 68 points do
    rng = np.random.default_rng(0)
    return rng.uniform(100, 300, size=(68, 2)) * scale + np.asarray(offset)


def test_landmark_error_hand_computed():
    a = np.zeros((4, 2))
    b = np.array([[3.0, 4.0], [0, 0], [0, 0], [0, 0]])  # one point 5 px away
    e = metrics.landmark_error_points(a, b)
    assert e.mse_px2 == pytest.approx(25 / 4)
    assert e.rms_px == pytest.approx(np.sqrt(25 / 4))


def test_landmark_error_known_shift_and_working_scale():
    p = _grid_points68()
    # a shift of (3, 4) px in a 500 px image is (6, 8) px at the 1000 px working size
    e = metrics.landmark_error_points(p, p + [3, 4], scale_a=2.0, scale_b=2.0)
    assert e.mse_px2 == pytest.approx(100.0)
    assert e.rms_px == pytest.approx(10.0)
    assert metrics.working_scale((500, 400, 3)) == pytest.approx(2.0)


def test_landmark_error_rejects_mismatched_sets():
    with pytest.raises(BadInputError):
        metrics.landmark_error_points(np.zeros((66, 2)), np.zeros((68, 2)))


def test_normalized_correlation_cases():
    rng = np.random.default_rng(1)
    p = rng.random((100, 100))
    assert metrics.normalized_correlation(p, p) == pytest.approx(1.0)
    assert metrics.normalized_correlation(p, -p) == pytest.approx(-1.0)
    assert metrics.normalized_correlation(p, 2 * p + 5) == pytest.approx(1.0)  # affine-invariant
    # hand-computed: p = [1,2,3], q = [1,3,2] -> cov 0.5·(...)= (−1·−1 + 0·1 + 1·0)/(√2·√2) = 0.5
    assert metrics.normalized_correlation([1, 2, 3], [1, 3, 2]) == pytest.approx(0.5)
    assert metrics.normalized_correlation(np.ones(9), p[:3, :3]) == 0.0  # flat patch: defined as 0


@pytest.fixture(scope="module")
def face():
    from facetex.io import read_image
    from facetex.landmarks import detect_face

    img = read_image(sample_path("frl_004_neutral.jpg"))
    return img, detect_face(img).points68


def test_skin_patches_lie_on_skin_and_scale_with_image(face):
    img, p68 = face
    patches = metrics.skin_patches(img, p68)
    assert set(patches) == set(metrics.SKIN_PATCHES)
    side = round(100 * 400 / 1000)
    for name, patch in patches.items():
        assert patch.shape == (side, side), name
        # skin: no strong edges (brows, eyes, background) inside the patch
        assert patch.std() < 0.1, name


def test_texture_similarity_identical_and_negative(face):
    img, p68 = face
    assert metrics.texture_similarity(img, img, points_a=p68, points_b=p68) == pytest.approx(1.0)
    s, per = metrics.texture_similarity(img, 1.0 - img, points_a=p68, points_b=p68, per_patch=True)
    assert s == pytest.approx(-1.0)
    assert all(v == pytest.approx(-1.0) for v in per.values())


def test_landmark_error_identical_images_is_zero(face):
    img, p68 = face
    e = metrics.landmark_error(img, img, points_a=p68, points_b=p68)
    assert e.mse_px2 == 0.0 and e.rms_px == 0.0


def test_identity_distance_same_image_near_zero(face):
    img, p68 = face
    assert metrics.identity_distance(img, img, points_a=p68, points_b=p68) < 1e-4


def test_metrics_cli_json(capsys):
    from facetex.cli import main

    a = str(sample_path("frl_004_neutral.jpg"))
    b = str(sample_path("frl_005_neutral.jpg"))
    assert main(["metrics", a, a, b, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"E_content", "E_style", "E_content_rms_px", "E_style_rms_px",
                        "S_content", "S_style", "identity_content", "identity_style", "S_style_none",
                        "S_style_gain", "detail_output", "detail_content", "detail_style", "detail_style_own",
                        "detail_ratio", "protected_change", "background_change",
                        # issue 22
                        "lowfreq_dE", "lowfreq_dE_max_region", "hair_leakage", "hair_leakage_style",
                        "stubble_output", "stubble_content", "stubble_style", "stubble_moved", "coverage",
                        "detail_moved", "detail_moved_cheeks", "detail_moved_cheeks_skin", "marks_content",
                        "marks_kept", "marks_style",
                        "marks_arrived"}
    # doing nothing: no colour change, no coverage, no detail or stubble moved, every mark kept
    assert out["lowfreq_dE"] == 0.0 and out["coverage"] == 0.0 and out["stubble_output"] == out["stubble_content"]
    assert out["detail_moved"] == 0.0 and out["marks_kept"] in (1.0, None)
    assert out["E_content"] == 0.0 and out["S_content"] == pytest.approx(1.0)
    # the content scored as its own output: no gain, no change, its own detail
    assert out["S_style_gain"] == 0.0 and out["protected_change"] == 0.0 and out["background_change"] == 0.0
    assert out["detail_output"] == out["detail_content"] > 0
    assert out["identity_content"] < 1e-4 and out["identity_style"] > 0.6
    assert out["E_style"] > 1.0


def test_skin_detail_hand_computed(face):
    """A flat image has no detail; a ±a checkerboard has high-pass std ≈ a (a σ = 2 px
    Gaussian keeps almost nothing of a 2 px period)."""
    _, p68 = face
    img = np.full((400, 400, 3), 0.5, np.float32)
    assert metrics.skin_detail(img, p68) == pytest.approx(0.0, abs=1e-4)
    yy, xx = np.mgrid[0:400, 0:400]
    board = img + (((yy + xx) % 2) * 2 - 1)[..., None].astype(np.float32) * (4 / 255.0)  # ±4 in 0–255 units
    assert 3.8 < metrics.skin_detail(board, p68) < 4.05


def test_detail_moved_on_skin_ignores_the_styles_moustache(face):
    """Style: the content's ±2 checkerboard skin with a ±12 'moustache' band over the lower part
    of the cheek patches (masked out of its skin); output: ±3 skin. Over the whole patch the style
    looks far rougher and the output moved little; over skin pixels it moved half the way."""
    _, p68 = face
    yy, xx = np.mgrid[0:400, 0:400]
    board = (((yy + xx) % 2) * 2 - 1)[..., None].astype(np.float32) / 255.0

    def img(a):
        return np.full((400, 400, 3), 0.5, np.float32) + a * board

    frames = metrics.skin_patch_frames(p68, (400, 400))
    band = np.zeros((400, 400), bool)  # the lower third of each cheek patch, in image pixels
    for k in ("left_cheek", "right_cheek"):
        to_image = cv2.invertAffineTransform(frames[k])
        for v in np.linspace(27, 40, 14):
            for u in np.linspace(0, 40, 41):
                x, y = to_image @ [u, v, 1.0]
                band[int(round(y)) - 1:int(round(y)) + 2, int(round(x)) - 1:int(round(x)) + 2] = True
    content, output = img(2.0), img(3.0)
    style = np.where(band[..., None], img(12.0), img(4.0))
    skin = np.ones((400, 400), np.float32)
    res = metrics.detail_moved(output, content, style, p68, p68, p68, skins=(skin, (~band).astype(np.float32)))
    assert res["cheeks_rougher"] < 0.3  # the moustache makes the style look rough
    assert res["cheeks_rougher_skin"] == pytest.approx(0.5, abs=0.05)
    assert "cheeks_rougher_skin" not in metrics.detail_moved(output, content, style, p68, p68, p68)


def test_protected_and_background_change_hand_computed(face):
    img, p68 = face
    from facetex.geometry.skin import protected_mask

    out = img.copy()
    m = protected_mask(p68, img.shape)
    out[m] = np.clip(out[m] + 10 / 255.0, 0, 1)  # +10 on the features only
    assert metrics.protected_change(out, img, points=p68) == pytest.approx(10.0, abs=0.6)
    assert metrics.background_change(out, img, points=p68) == 0.0
    bg = ~metrics.face_area_mask(img, p68)
    out2 = img.copy()
    out2[bg] = np.clip(out2[bg] - 5 / 255.0, 0, 1)
    assert metrics.background_change(out2, img, points=p68) == pytest.approx(5.0, abs=0.6)
    assert metrics.protected_change(out2, img, points=p68) == 0.0
