"""Tests of facetex.geometry.flow: utilities (hand-computed cases), optical_flow, sift_flow."""

from __future__ import annotations

import cv2
import dlib
import numpy as np
import pytest

from facetex._resources import model_path, sample_path
from facetex.errors import BadInputError
from facetex.geometry._sift_flow import dense_sift
from facetex.geometry.flow import (
    compose_flows,
    flow_epe,
    flow_from_map,
    invert_flow,
    map_from_flow,
    optical_flow,
    sift_flow,
    warp_with_flow,
)

SIZE = 256


def const_flow(h, w, dx, dy):
    f = np.empty((h, w, 2), np.float32)
    f[..., 0], f[..., 1] = dx, dy
    return f


def grid(h, w):
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    return xs, ys


# --- utilities ---------------------------------------------------------------

def test_warp_integer_shift_is_exact():
    img = np.random.default_rng(0).random((20, 30, 3)).astype(np.float32)
    out = warp_with_flow(img, const_flow(20, 30, 2, 1))
    np.testing.assert_array_equal(out[:-1, :-2], img[1:, 2:])  # out(x) = img(x + (2, 1))
    np.testing.assert_array_equal(out[:, -1], img[np.minimum(np.arange(20) + 1, 19), -1])  # replicate


def test_warp_fractional_shift_on_linear_ramp():
    xs, ys = grid(16, 16)
    img = 3 * xs + 2 * ys
    out = warp_with_flow(img, const_flow(16, 16, 0.5, 0.25))
    np.testing.assert_allclose(out[:-1, :-1], img[:-1, :-1] + 3 * 0.5 + 2 * 0.25, atol=1e-3)


def test_warp_constant_border_dtypes_and_channels():
    img = np.full((8, 8, 6), 7, np.uint8)  # > 4 channels: cv2.remap is chunked
    out = warp_with_flow(img, const_flow(8, 8, -3, 0), border="constant")
    assert out.dtype == np.uint8 and out.shape == img.shape
    assert (out[:, :3] == 0).all() and (out[:, 3:] == 7).all()
    gray = warp_with_flow(np.ones((8, 8), np.float32), const_flow(8, 8, 0, 0))
    assert gray.shape == (8, 8)
    with pytest.raises(BadInputError):
        warp_with_flow(img, const_flow(8, 9, 0, 0))
    with pytest.raises(BadInputError):
        warp_with_flow(img, const_flow(8, 8, 0, 0), border="wrap")


def test_map_flow_round_trip():
    f = np.random.default_rng(1).normal(size=(5, 7, 2)).astype(np.float32)
    m = map_from_flow(f)
    assert m[2, 3, 0] == pytest.approx(3 + f[2, 3, 0]) and m[2, 3, 1] == pytest.approx(2 + f[2, 3, 1])
    np.testing.assert_allclose(flow_from_map(m), f, atol=1e-5)
    img = np.random.default_rng(2).random((5, 7)).astype(np.float32)
    np.testing.assert_allclose(
        warp_with_flow(img, f),
        cv2.remap(img, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE),
    )


def test_compose_two_shifts():
    c = compose_flows(const_flow(10, 10, 1, 2), const_flow(10, 10, 3, -1))
    np.testing.assert_allclose(c, const_flow(10, 10, 4, 1))


def test_compose_two_scalings():
    # f_ab(x) = 0.1 x, f_bc(x) = 0.2 x  ->  f_ac(x) = 0.1 x + 0.2 (x + 0.1 x) = 0.32 x
    xs, _ = grid(1, 40)
    f_ab = np.stack([0.1 * xs, 0 * xs], -1)
    f_bc = np.stack([0.2 * xs, 0 * xs], -1)
    c = compose_flows(f_ab, f_bc)
    inner = xs[0] * 1.1 <= 39
    # cv2.remap quantises sampling positions to 1/32 px: error <= slope 0.2 * 1/64
    np.testing.assert_allclose(c[0, inner, 0], 0.32 * xs[0, inner], atol=4e-3)


def test_compose_matches_sequential_warps():
    rng = np.random.default_rng(3)
    h = w = 64
    xs, ys = grid(h, w)
    img = np.sin(xs / 5) + np.cos(ys / 7)
    f_ab = np.stack([1.5 * np.sin(ys / 10), 1.0 * np.cos(xs / 9)], -1).astype(np.float32)
    f_bc = np.stack([np.full_like(xs, 2.3), 0.8 * np.sin(xs / 8 + rng.random())], -1).astype(np.float32)
    seq = warp_with_flow(warp_with_flow(img, f_bc), f_ab)
    once = warp_with_flow(img, compose_flows(f_ab, f_bc))
    np.testing.assert_allclose(seq[8:-8, 8:-8], once[8:-8, 8:-8], atol=0.02)


def test_invert_affine_flow():
    h = w = 64
    xs, ys = grid(h, w)
    m = np.array([[1.05, 0.03], [-0.02, 0.97]])
    t = np.array([2.0, -1.5])
    fwd = np.stack([m[0, 0] * xs + m[0, 1] * ys + t[0] - xs, m[1, 0] * xs + m[1, 1] * ys + t[1] - ys], -1)
    inv = invert_flow(fwd.astype(np.float32))
    mi = np.linalg.inv(m)  # inverse map y -> M^-1 (y - t)
    ex = mi[0, 0] * (xs - t[0]) + mi[0, 1] * (ys - t[1]) - xs
    ey = mi[1, 0] * (xs - t[0]) + mi[1, 1] * (ys - t[1]) - ys
    sl = np.s_[10:-10, 10:-10]
    np.testing.assert_allclose(inv[sl][..., 0], ex[sl], atol=1e-2)
    np.testing.assert_allclose(inv[sl][..., 1], ey[sl], atol=1e-2)
    np.testing.assert_allclose(compose_flows(inv, fwd)[sl], 0, atol=1e-2)


def test_flow_epe_hand_case():
    a = np.zeros((4, 4, 2), np.float32)
    b = const_flow(4, 4, 3, 4)
    b[:2] = 0
    assert flow_epe(a, b) == pytest.approx(2.5)
    mask = np.zeros((4, 4), bool)
    mask[2:] = True
    assert flow_epe(a, b, mask) == pytest.approx(5.0)
    with pytest.raises(BadInputError):
        flow_epe(a, b, np.zeros((4, 4), bool))
    with pytest.raises(BadInputError):
        flow_epe(a, np.zeros((4, 4, 3), np.float32))


# --- real faces --------------------------------------------------------------

def read_face(name: str) -> np.ndarray:
    return cv2.cvtColor(cv2.imread(str(sample_path(name))), cv2.COLOR_BGR2RGB).astype(np.float32) / 255


@pytest.fixture(scope="module")
def landmarker():
    det = dlib.get_frontal_face_detector()
    sp = dlib.shape_predictor(str(model_path("shape_predictor_68_face_landmarks.dat")))

    def run(img):
        u8 = np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8)
        rect = max(det(u8, 0) or det(u8, 1), key=lambda r: r.area())
        return np.array([(p.x, p.y) for p in sp(u8, rect).parts()], np.float64)

    return run


def face_mask(shape, pts):
    m = np.zeros(shape[:2], np.uint8)
    cv2.fillConvexPoly(m, cv2.convexHull(pts.astype(np.int32)), 1)
    return m.astype(bool)


@pytest.fixture(scope="module")
def warped_face(landmarker):
    """(A, B, F, mask): B = bundled face at 256², A = B's full-res photo warped by a smooth F, so flow A->B = F."""
    img = read_face("frl_004_neutral.jpg")
    rng = np.random.default_rng(7)
    ys, xs = np.mgrid[0:SIZE, 0:SIZE] / SIZE
    f = np.zeros((SIZE, SIZE, 2))
    for c in range(2):
        for _ in range(4):
            fx, fy = rng.uniform(-2, 2, 2)
            f[..., c] += rng.normal() * np.sin(2 * np.pi * (fx * xs + fy * ys) + rng.uniform(0, 2 * np.pi))
    f = (f * 6.0 / np.sqrt((f ** 2).sum(2)).max()).astype(np.float32)
    h = img.shape[0]
    big = cv2.resize(f, (h, h), interpolation=cv2.INTER_CUBIC) * (h / SIZE)
    a = cv2.resize(warp_with_flow(img, big), (SIZE, SIZE), interpolation=cv2.INTER_AREA)
    b = cv2.resize(img, (SIZE, SIZE), interpolation=cv2.INTER_AREA)
    mask = face_mask(b.shape, landmarker(b))
    assert flow_epe(np.zeros_like(f), f, mask) > 1.5  # the warp is not trivial inside the face
    return a, b, f, mask


def test_optical_flow_recovers_smooth_warp(warped_face):
    a, b, f, mask = warped_face
    est = optical_flow(a, b)
    assert est.shape == f.shape and est.dtype == np.float32
    assert flow_epe(est, f, mask) < 0.5
    # and warping B by it reproduces A
    assert np.abs(warp_with_flow(b, est) - a)[mask].mean() < 0.5 * np.abs(b - a)[mask].mean()


@pytest.mark.parametrize("method", ["dis", "farneback"])
def test_optical_flow_other_methods(warped_face, method):
    a, b, f, mask = warped_face
    assert flow_epe(optical_flow(a, b, method=method), f, mask) < 0.6


def test_optical_flow_alpha_smooths(warped_face):
    a, b, _, _ = warped_face
    tv = lambda fl: np.abs(np.diff(fl, axis=0)).mean() + np.abs(np.diff(fl, axis=1)).mean()  # noqa: E731
    noisy = np.clip(b + np.random.default_rng(0).normal(0, 0.03, b.shape), 0, 1).astype(np.float32)
    assert tv(optical_flow(a, noisy, alpha=0.3)) < tv(optical_flow(a, noisy, alpha=0.02))


def test_optical_flow_bad_input():
    x = np.zeros((32, 32, 3), np.float32)
    with pytest.raises(BadInputError):
        optical_flow(x, x, method="deepflow")
    with pytest.raises(BadInputError):
        optical_flow(x, np.zeros((32, 30, 3), np.float32))


def test_sift_flow_recovers_smooth_warp(warped_face):
    a, b, f, mask = warped_face
    calls = []
    est = sift_flow(a, b, progress=lambda n=1, **kw: calls.append(kw))
    assert est.shape == f.shape and est.dtype == np.float32
    assert flow_epe(est, f, mask) < 1.5
    assert [c["level"] for c in calls][-1] == 0 and len(calls) >= 3


def test_sift_flow_aligns_different_people(landmarker):
    a = cv2.resize(read_face("frl_004_neutral.jpg"), (SIZE, SIZE), interpolation=cv2.INTER_AREA)
    b = cv2.resize(read_face("frl_005_neutral.jpg"), (SIZE, SIZE), interpolation=cv2.INTER_AREA)
    la, lb = landmarker(a), landmarker(b)
    eyes = lambda p: np.array([p[36:42].mean(0), p[42:48].mean(0)], np.float32)  # noqa: E731
    sim, _ = cv2.estimateAffinePartial2D(eyes(lb), eyes(la))
    b = cv2.warpAffine(b, sim, (SIZE, SIZE), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    mask = face_mask(a.shape, la)
    bw = warp_with_flow(b, sift_flow(a, b))
    gray = lambda x: cv2.cvtColor(x, cv2.COLOR_RGB2GRAY)  # noqa: E731
    da = dense_sift(gray(a))
    desc_before = np.abs(da - dense_sift(gray(b))).sum(2)[mask].mean()
    desc_after = np.abs(da - dense_sift(gray(bw))).sum(2)[mask].mean()
    gray_before = np.abs(gray(a) - gray(b))[mask].mean()
    gray_after = np.abs(gray(a) - gray(bw))[mask].mean()
    assert desc_after < 0.8 * desc_before
    assert gray_after < 0.8 * gray_before


def test_sift_flow_bad_input():
    x = np.zeros((32, 32), np.float32)
    with pytest.raises(BadInputError):
        sift_flow(x, x, smoothness=3)
    with pytest.raises(BadInputError):
        sift_flow(x, x, descriptor="hog")
