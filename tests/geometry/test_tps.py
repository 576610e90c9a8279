import math

import cv2
import numpy as np
import pytest
from scipy.interpolate import RBFInterpolator

from facetex._resources import sample_path
from facetex.errors import BadInputError
from facetex.geometry.tps import ThinPlateSpline, tps_kernel, tps_warp
from facetex.landmarks import detect_face


def _load(name):
    return cv2.imread(str(sample_path(name)))[..., ::-1].astype(np.float32) / 255.0


@pytest.fixture(scope="module")
def fiducials():
    """(target, source): landmarks of frl_004 (target) and frl_005 (source), 400 px."""
    t = detect_face(_load("frl_004_neutral.jpg")).points68
    s = detect_face(_load("frl_005_neutral.jpg")).points68
    return t, s


def _objective(tps: ThinPlateSpline, target, source, lam):
    # Tom Hanks Eq. 1, with the smoothness term from our own bending_energy
    return float(((source - tps(target)) ** 2).sum()) + lam * tps.bending_energy()


def test_kernel_hand_values():
    assert tps_kernel(np.array([0.0]))[0] == 0.0
    assert tps_kernel(np.array([1.0]))[0] == 0.0
    assert tps_kernel(np.array([math.e]))[0] == pytest.approx(math.e**2)


def test_lambda0_interpolates_fiducials(fiducials):
    t, s = fiducials
    tps = ThinPlateSpline.fit(t, s, smoothing=0)
    assert np.abs(tps(t) - s).max() < 0.01
    # the dense map at (integer) target pixels samples the source fiducials
    ti = np.round(t)
    m = ThinPlateSpline.fit(ti, s, smoothing=0).dense_map((400, 400))
    got = m[ti[:, 1].astype(int), ti[:, 0].astype(int)]
    assert np.abs(got - s).max() < 0.01


def test_smoothing_lowers_bending_energy(fiducials):
    t, s = fiducials
    e = [ThinPlateSpline.fit(t, s, smoothing=lam).bending_energy() for lam in (0, 1, 10, 100)]
    assert e[0] > e[1] > e[2] > e[3] > 0
    # and stops interpolating
    assert np.abs(ThinPlateSpline.fit(t, s, smoothing=10)(t) - s).max() > 0.1


def test_affine_data_has_zero_bending_for_any_lambda():
    rng = np.random.default_rng(1)
    t = rng.uniform(0, 100, (12, 2))
    A = np.array([[1.1, 0.2], [-0.3, 0.9]])
    s = t @ A.T + [5.0, -7.0]
    for lam in (0, 10):
        tps = ThinPlateSpline.fit(t, s, smoothing=lam)
        assert tps.bending_energy() == pytest.approx(0.0, abs=1e-9)
        q = rng.uniform(-50, 150, (20, 2))
        np.testing.assert_allclose(tps(q), q @ A.T + [5.0, -7.0], atol=1e-8)


def test_lambda_equals_scipy_smoothing_over_8pi(fiducials):
    t, s = fiducials
    q = np.random.default_rng(0).uniform(0, 400, (300, 2))
    for lam in (0.0, 10.0):
        ours = ThinPlateSpline.fit(t, s, smoothing=lam)(q)
        ref = RBFInterpolator(t, s, kernel="thin_plate_spline", smoothing=8 * math.pi * lam)(q)
        np.testing.assert_allclose(ours, ref, atol=1e-5)


def test_bending_energy_matches_numerical_integral():
    # J = integral of r_xx^2 + 2 r_xy^2 + r_yy^2 over the plane, by quadrature of the
    # analytic second derivatives of phi = r^2 log r: phi_xx = 2 log r + 2 x^2/r^2 + 1, ...
    rng = np.random.default_rng(0)
    c = rng.uniform(-1, 1, (6, 2))
    tps = ThinPlateSpline.fit(c, rng.normal(size=(6, 2)) * 0.3, smoothing=0)
    h, L = 0.025, 10.0
    xs = np.arange(-L, L, h) + h / 2
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    fxx = np.zeros(X.shape + (2,))
    fxy, fyy = np.zeros_like(fxx), np.zeros_like(fxx)
    for k in range(6):
        dx, dy = X - c[k, 0], Y - c[k, 1]
        r2 = dx * dx + dy * dy
        lr = np.log(r2)  # 2 log r
        w = tps.weights[k]
        fxx += (lr + 2 * dx * dx / r2 + 1)[..., None] * w
        fyy += (lr + 2 * dy * dy / r2 + 1)[..., None] * w
        fxy += (2 * dx * dy / r2)[..., None] * w
    J = float((fxx**2 + 2 * fxy**2 + fyy**2).sum() * h * h)
    assert tps.bending_energy() == pytest.approx(J, rel=0.02)


def test_fit_minimises_eq1_against_perturbations(fiducials):
    t, s = fiducials
    lam = 10.0
    best = ThinPlateSpline.fit(t, s, smoothing=lam)
    e0 = _objective(best, t, s, lam)
    rng = np.random.default_rng(2)
    P = np.hstack([np.ones((len(t), 1)), t])
    # perturb W inside the side conditions P^T W = 0 (null space of P^T), and A freely
    null = np.linalg.svd(P.T)[2][3:].T
    for scale in (1e-4, 1e-3, 1e-2):
        for _ in range(5):
            dw = null @ rng.normal(size=(null.shape[1], 2)) * scale * np.abs(best.weights).max()
            da = rng.normal(size=(3, 2)) * scale * np.array([[1.0], [1e-2], [1e-2]])
            other = ThinPlateSpline(best.centres, best.weights + dw, best.affine + da, lam)
            assert _objective(other, t, s, lam) > e0
    # the lambda-0 interpolant is worse under the lambda-10 objective too
    assert _objective(ThinPlateSpline.fit(t, s, smoothing=0), t, s, lam) > e0


def test_dense_map_coarse_matches_direct(fiducials):
    t, s = fiducials
    for lam in (0, 10):
        tps = ThinPlateSpline.fit(t, s, smoothing=lam)
        direct = tps.dense_map((400, 400), step=1)
        assert np.abs(tps.dense_map((400, 400), step=8) - direct).max() < 0.02


def test_tps_warp_moves_a_dot_to_its_target():
    src = np.array([[20, 20], [80, 20], [20, 80], [80, 80], [50, 50]], float)
    dst = src.copy()
    dst[4] = [58, 44]
    img = np.zeros((100, 100), np.float32)
    img[50, 50] = 1.0
    img = cv2.GaussianBlur(img, (0, 0), 1.5)
    out = tps_warp(img, src, dst, smoothing=0)
    y, x = np.unravel_index(np.argmax(out), out.shape)
    assert (x, y) == (58, 44)


def test_bad_inputs():
    with pytest.raises(BadInputError):
        ThinPlateSpline.fit(np.zeros((2, 2)), np.zeros((2, 2)))
    with pytest.raises(BadInputError):
        ThinPlateSpline.fit(np.zeros((5, 2)), np.zeros((4, 2)))
    with pytest.raises(BadInputError):
        ThinPlateSpline.fit(np.eye(3, 2), np.eye(3, 2), smoothing=-1)


def test_evaluate_many_equals_separate_fits():
    from facetex.geometry.tps import tps_evaluate_many

    rng = np.random.default_rng(3)
    target = rng.uniform(0, 100, (12, 2))
    sources = target[None] + rng.normal(scale=4.0, size=(5, 12, 2))
    pts = rng.uniform(-10, 110, (40, 2))
    for lam in (0.0, 10.0):
        many = tps_evaluate_many(target, sources, pts, smoothing=lam)
        assert many.shape == (5, 40, 2)
        for k in range(5):
            np.testing.assert_allclose(many[k], ThinPlateSpline.fit(target, sources[k], smoothing=lam)(pts),
                                       atol=1e-9)
    with pytest.raises(BadInputError, match="source_pts"):
        tps_evaluate_many(target, sources[:, :5], pts)
