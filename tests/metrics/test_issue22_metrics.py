"""Issue 22 measures (facetex.metrics): low-frequency skin ΔE, hair leakage (coherence),
stubble (dark specks), coverage, detail moved, marks — hand-computed cases."""

import cv2
import numpy as np
import pytest

from facetex import metrics
from facetex._resources import sample_path
from facetex.landmarks import detect_face


@pytest.fixture(scope="module")
def face():
    img = cv2.imread(str(sample_path("frl_004_neutral.jpg")))[..., ::-1].astype(np.float32) / 255.0
    return img.shape[:2], detect_face(img).points68


def test_lowfreq_delta_e_of_a_uniform_shift_is_its_lab_distance(face):
    shape, p = face
    content = np.full(shape + (3,), 0.6, np.float32)
    output = content + np.array([0.04, 0.0, -0.02], np.float32)
    skin = np.ones(shape, np.float32)
    got = metrics.lowfreq_skin_delta_e(output, content, p, skin=skin)
    lab = [cv2.cvtColor(x[:1, :1], cv2.COLOR_RGB2LAB)[0, 0].astype(np.float64) for x in (output, content)]
    want = float(np.linalg.norm(lab[0] - lab[1]))
    assert want > 1.0
    assert got["mean"] == pytest.approx(want, rel=1e-4)
    assert got["max_region"] == pytest.approx(want, rel=1e-4)
    assert metrics.lowfreq_skin_delta_e(content, content, p, skin=skin)["mean"] == 0.0
    # pixel-scale detail of zero mean hardly moves the low-frequency colour
    checker = 0.05 * ((np.indices(shape).sum(0) % 2) * 2 - 1)[..., None].astype(np.float32)
    assert metrics.lowfreq_skin_delta_e(content + checker, content, p, skin=skin)["mean"] < 0.05


def test_structure_coherence_stripes_one_checks_zero():
    y, x = np.mgrid[:96, :96].astype(np.float64)
    stripes = np.sin(2 * np.pi * x / 8)
    assert metrics.structure_coherence(stripes, rho=8.0) == pytest.approx(1.0, abs=1e-3)
    # sin x + sin y: the tensor averaged over whole periods is isotropic
    checks = np.sin(2 * np.pi * x / 8) + np.sin(2 * np.pi * y / 8)
    inner = np.zeros(checks.shape, bool)
    inner[24:72, 24:72] = True
    assert metrics.structure_coherence(checks, inner, rho=8.0) < 0.05


def test_dark_speck_density_counts_specks_per_1000_px():
    img = np.full((1000, 1000, 3), 0.6, np.float32)
    mask = np.zeros((1000, 1000), bool)
    mask[100:300, 100:300] = True  # 40 000 px
    for i in range(10):  # ten 3 × 3 specks 0.2 darker, inside
        y, x = 120 + 16 * i, 150
        img[y:y + 3, x:x + 3] = 0.4
    img[500:503, 500:503] = 0.4  # one outside the mask
    img[200:260, 200:260] = 0.3  # a large dark piece (a shadow), not a speck
    assert metrics.dark_speck_density(img, mask) == pytest.approx(10 * 1000 / 40000)


def test_stubble_regions_lie_between_nose_and_lips_and_below_the_lip(face):
    shape, p = face
    r = metrics.stubble_regions(p, shape)
    ys, xs = np.nonzero(r["upper_lip"])
    assert p[33, 1] - 2 <= ys.mean() <= p[51, 1] and p[48, 0] <= xs.mean() <= p[54, 0]
    ys, xs = np.nonzero(r["chin"])
    assert p[57, 1] <= ys.mean() <= p[8, 1]
    assert not (r["upper_lip"] & r["chin"]).any()


def test_coverage_of_a_half_changed_skin(face):
    shape, p = face
    content = np.full(shape + (3,), 0.5, np.float32)
    output = content.copy()
    output[:, : shape[1] // 2] += 10 / 255  # left half changed by 10/255
    skin = np.zeros(shape, np.float32)
    skin[100:300, 100:300] = 1
    assert metrics.skin_coverage(output, content, p, skin=skin) == pytest.approx(0.5, abs=0.01)
    assert metrics.skin_coverage(content, content, p, skin=skin) == 0.0


def test_detail_moved_halfway(face):
    shape, p = face
    rng = np.random.default_rng(0)

    def noisy(std):
        return np.clip(0.5 + rng.normal(0, std / 255, shape + (1,)), 0, 1).repeat(3, 2).astype(np.float32)

    got = metrics.detail_moved(noisy(4.0), noisy(2.0), noisy(6.0), p, p, p)
    assert got["mean"] == pytest.approx(0.5, abs=0.06)
    assert got["cheeks_rougher"] == pytest.approx(0.5, abs=0.06)
    smoother = metrics.detail_moved(noisy(4.0), noisy(6.0), noisy(2.0), p, p, p)
    assert np.isnan(smoother["cheeks_rougher"])  # the style is not rougher: not counted


def test_mark_survival_counts_kept_and_arrived(face):
    shape, p = face
    base = np.full(shape, 0.6, np.float32)
    yy, xx = np.mgrid[:shape[0], :shape[1]]

    def mole(x, y):
        return (0.3 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 2.0**2))).astype(np.float32)

    c_xy = p[[2, 31, 41, 48]].mean(0)  # left cheek
    s_xy = p[[14, 35, 46, 54]].mean(0)  # right cheek
    content = np.stack([base - mole(*c_xy)] * 3, -1)
    style = np.stack([base - mole(*s_xy)] * 3, -1)
    skin = np.ones(shape, np.float32)
    both = np.stack([base - mole(*c_xy) - mole(*s_xy)] * 3, -1)
    got = metrics.mark_survival(both, content, style, p, skin=skin, style_skin=skin)
    assert got == {"content": 1, "style": 1, "kept": 1.0, "arrived": 1.0}
    got = metrics.mark_survival(style, content, style, p, skin=skin, style_skin=skin)
    assert got["kept"] == 0.0 and got["arrived"] == 1.0
