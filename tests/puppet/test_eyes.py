"""The driver's eyeballs in the puppet's lids (facetex.puppet.eyes), on hand-computed cases."""

from __future__ import annotations

import importlib

import cv2
import numpy as np
import pytest

from facetex.errors import BadInputError
from facetex.puppet.composite import CompositeParams, composite_face
from facetex.puppet.eyes import _lightness_to_y, eye_interior, iris_shift, persona_iris
from facetex.puppet.lighting import srgb_to_linear


def _eyes68(cx=48.0, cy=40.0, half=8.0, gap=6.0, apart=24.0):
    """iBUG-68 points with both eye contours set: corners ``2 * half`` apart, upper lid points
    ``gap / 2`` above the corner line, lower ones below; the eyes ``apart`` px between centres."""
    p = np.full((68, 2), np.nan)
    p[:36] = (cx, cy + 20)
    p[48:] = (cx, cy + 20)
    for first, ex in ((36, cx - apart / 2), (42, cx + apart / 2)):
        p[first:first + 6] = [(ex - half, cy), (ex - half / 3, cy - gap / 2), (ex + half / 3, cy - gap / 2),
                              (ex + half, cy), (ex + half / 3, cy + gap / 2), (ex - half / 3, cy + gap / 2)]
    return p


def _eye_frame(d68, h=80, w=96):
    """Skin (0.7, 0.55, 0.45) with each driver eye split at its centre: its left half green
    (0.2, 0.6, 0.3), its right half white (0.9, 0.9, 0.9)."""
    f = np.zeros((h, w, 3), np.float32)
    f[:] = (0.7, 0.55, 0.45)
    for first in (36, 42):
        e = d68[first:first + 6]
        m = cv2.fillPoly(np.zeros((h, w), np.uint8), [np.round(e * 16).astype(np.int32)], 1, shift=4) > 0
        cxe = e[:, 0].mean()
        xx = np.arange(w)[None, :].repeat(h, 0)
        f[m & (xx < cxe)] = (0.2, 0.6, 0.3)
        f[m & (xx >= cxe)] = (0.9, 0.9, 0.9)
    return f


def test_eye_interior_moves_each_half_of_the_drivers_eye_to_the_same_half_of_the_puppets():
    d68 = _eyes68(gap=8.0)
    p68 = _eyes68(cx=50.0, cy=42.0, half=10.0, gap=6.0)  # moved, wider and narrower
    frame = _eye_frame(d68)
    img, alpha = eye_interior(frame, d68, p68)
    for first in (36, 42):
        ex, ey = p68[first:first + 6].mean(axis=0)
        # a quarter of the way in from each corner, on the lid line's middle: deep inside
        left, right = (int(round(ex - 5)), int(round(ey))), (int(round(ex + 5)), int(round(ey)))
        assert alpha[left[1], left[0]] == pytest.approx(1.0, abs=1e-6)
        np.testing.assert_allclose(img[left[1], left[0]], (0.2, 0.6, 0.3), atol=1e-5)
        np.testing.assert_allclose(img[right[1], right[0]], (0.9, 0.9, 0.9), atol=1e-5)
    # nothing outside the puppet's lids: above the upper lid and beyond the corners
    ex, ey = p68[36:42].mean(axis=0)
    assert alpha[int(ey - 5), int(ex)] == 0 and alpha[int(ey), int(ex - 12)] == 0
    # the soft edge: lower at the lid line than half the opening in
    assert 0 < alpha[int(round(ey - 2)), int(round(ex))] < alpha[int(round(ey)), int(round(ex))]


def test_eye_interior_fades_out_as_the_drivers_eye_closes():
    p68 = _eyes68(gap=6.0)
    # opening / width: 6/16 open (full), 1.8/16 (between 0.08 and 0.16: part), 1/16 closed (none)
    full = eye_interior(_eye_frame(_eyes68(gap=6.0)), _eyes68(gap=6.0), p68)[1].max()
    part = eye_interior(_eye_frame(_eyes68(gap=1.8)), _eyes68(gap=1.8), p68)[1].max()
    shut = eye_interior(_eye_frame(_eyes68(gap=1.0)), _eyes68(gap=1.0), p68)[1].max()
    t = (1.8 / 16 - 0.08) / 0.08
    assert full == pytest.approx(1.0) and part == pytest.approx(t * t * (3 - 2 * t), abs=1e-6) and shut == 0


def test_eye_interior_edge_stays_a_few_pixels_wide_on_large_eyes():
    """A 1000 px driver's eye (opening 30 px): the soft edge is 4 px (``soft_px``), not 0.3 x 30 =
    9 px; an eye of a 256 px frame (opening 8 px: 2.4 px) is unchanged."""
    from facetex.puppet._contours import EYE, sample_between

    for gap, scale in ((30.0, 5.0), (8.0, 1.0)):
        d68 = _eyes68(cx=48 * scale, cy=40 * scale, half=8 * scale, gap=gap, apart=24 * scale)
        frame = _eye_frame(d68, h=int(80 * scale), w=int(96 * scale))
        _, capped = eye_interior(frame, d68, d68)
        _, wide = eye_interior(frame, d68, d68, soft_px=None)
        s = sample_between(frame, d68[36:42], d68[36:42], frame.shape[:2], layout=EYE)
        x0, y0, x1, y1 = s.box
        g = float(s.gap.max())
        if 0.3 * g > 4:
            np.testing.assert_allclose(capped[y0:y1, x0:x1], s.edge(4.0 / g), atol=1e-6)
            np.testing.assert_allclose(wide[y0:y1, x0:x1], s.edge(0.3), atol=1e-6)
            assert capped.sum() > wide.sum() + 50  # the whites reach closer to the lids
        else:
            np.testing.assert_array_equal(capped, wide)


def test_eye_interior_skips_missing_eyes_and_rejects_wrong_shapes():
    d68, p68 = _eyes68(), _eyes68()
    p68[42:48] = np.nan  # the right eye is not tracked
    _, alpha = eye_interior(_eye_frame(d68), d68, p68)
    assert alpha[:, :48].max() == 1 and alpha[:, 50:].max() == 0
    with pytest.raises(BadInputError, match=r"\(68, 2\)"):
        eye_interior(_eye_frame(d68), d68[:48], p68)


def test_lightness_to_y_inverts_cielab_lightness():
    assert _lightness_to_y(100.0) == pytest.approx(1.0)
    assert _lightness_to_y(50.0) == pytest.approx(0.18419, abs=1e-5)
    assert _lightness_to_y(4.0) == pytest.approx(4.0 / 903.3, rel=1e-3)  # the linear toe


def test_iris_shift_moves_the_dark_part_to_the_target_within_the_lightness_bound():
    # a driver eye of 60 % whites (L* 80) and 40 % iris (L* 40, a* -10, b* 5)
    eye = np.array([[80.0, 0.0, 0.0]] * 6 + [[40.0, -10.0, 5.0]] * 4)
    lin = np.float32([0.4, 0.2, 0.1])  # the target, linear RGB
    want = cv2.cvtColor(lin[None, None], cv2.COLOR_LRGB2Lab)[0, 0]  # L* 58.6: 18.6 above the iris
    assert want[0] - 40 > 10
    shift, light, dark = iris_shift(eye, lin)
    assert light == pytest.approx(80.0) and dark == pytest.approx(40.0)
    assert shift[0] == pytest.approx(10.0, abs=1e-3)  # bounded: at most 10 L* lighter
    # the target scaled to L* 50 keeps its chromaticity: the hue angle of its a*, b*
    scaled = cv2.cvtColor((lin * _lightness_to_y(50.0) / _lightness_to_y(float(want[0])))[None, None],
                          cv2.COLOR_LRGB2Lab)[0, 0]
    np.testing.assert_allclose(shift, scaled - [40.0, -10.0, 5.0], atol=1e-3)


def test_persona_iris_is_the_iris_to_skin_ratio_in_linear_light():
    h, w = 120, 100
    p = _eyes68(cx=50, cy=45, half=9, gap=8, apart=40)
    # cheeks and nose bridge for the skin sample (facetex.geometry.skin._sample_regions)
    p[2], p[14], p[31], p[35], p[48], p[54] = (15, 70), (85, 70), (44, 70), (56, 70), (38, 90), (62, 90)
    p[28], p[30], p[0], p[16] = (50, 48), (50, 65), (10, 45), (90, 45)
    skin, iris = np.float32([0.8, 0.6, 0.5]), np.float32([0.3, 0.35, 0.5])
    img = np.zeros((h, w, 3), np.float32)
    img[:] = skin
    for first in (36, 42):
        m = cv2.fillPoly(np.zeros((h, w), np.uint8), [np.round(p[first:first + 6]).astype(np.int32)], 1) > 0
        img[m] = iris
    u8 = np.round(img * 255).astype(np.uint8)
    got = persona_iris(u8[None].repeat(3, 0), p[None].repeat(3, 0))
    want = srgb_to_linear(np.round(iris * 255) / 255) / srgb_to_linear(np.round(skin * 255) / 255)
    np.testing.assert_allclose(got, want, rtol=1e-4)
    p_bad = np.full((1, 68, 2), np.nan)
    assert persona_iris(u8[None], p_bad) is None


def test_composite_draws_the_drivers_eyes_with_the_personas_iris_only_when_asked(monkeypatch):
    """composite_face hands eye_interior the frame, both faces' landmarks (box px) and the iris
    target (the persona's ratio times the driver's skin, linear), and skips it with the persona's eyes."""
    comp = importlib.import_module("facetex.puppet.composite")
    calls = []

    def spy(frame, d68, p68, shape, *, iris):
        calls.append((np.asarray(frame).shape, shape, np.asarray(d68).copy(), None if iris is None else iris.copy()))
        return np.zeros(np.asarray(frame).shape, np.float32), np.zeros(shape, np.float32)

    monkeypatch.setattr(comp, "eye_interior", spy)
    h, w = 96, 96
    yy, xx = np.mgrid[0:h, 0:w]
    frame = np.zeros((h, w, 3), np.float32)
    frame[:] = (0.1, 0.5, 0.8)
    frame[((xx - 48) / 26.0) ** 2 + ((yy - 50) / 32.0) ** 2 <= 1] = (0.55, 0.4, 0.3)
    coverage = (((xx - 48) / 34.0) ** 2 + ((yy - 50) / 38.0) ** 2 <= 1).astype(np.float32)
    t = np.linspace(0, 2 * np.pi, 36, endpoint=False)
    oval = np.c_[48 + 26 * np.cos(t), 50 + 32 * np.sin(t)]
    p68 = np.zeros((68, 2))
    p68[:] = (48, 50)
    p68[36:48] = _eyes68(cx=48, cy=42, half=5, gap=4, apart=24)[36:48]
    puppet = np.broadcast_to(np.float32([0.85, 0.75, 0.75]), (h, w, 3)).copy()
    ratio = np.float32([0.5, 0.25, 0.125])
    composite_face(frame, puppet, coverage, None, driver_oval=oval, driver_points68=p68, puppet_points68=p68,
                   iris=ratio)
    assert len(calls) == 1
    fr_shape, shape, d68, target = calls[0]
    assert fr_shape[:2] == shape and np.allclose(p68 - d68, p68[0] - d68[0])
    np.testing.assert_allclose(target, ratio * srgb_to_linear(np.float32([0.55, 0.4, 0.3])), rtol=1e-3)
    calls.clear()
    composite_face(frame, puppet, coverage, None, driver_oval=oval, driver_points68=p68, puppet_points68=p68)
    assert calls[0][3] is None  # no persona ratio: the driver's own iris colour
    calls.clear()
    composite_face(frame, puppet, coverage, None, driver_oval=oval, driver_points68=p68, puppet_points68=p68,
                   iris=ratio, params=CompositeParams(eyes="persona"))
    assert calls == []


def test_eye_interior_survives_degenerate_and_off_frame_eyes():
    d68, p68 = _eyes68(), _eyes68()
    frame = _eye_frame(d68)
    flat = p68.copy()
    flat[36:42] = flat[36:42].mean(axis=0)  # a puppet eye shrunk to a point: nothing drawn there
    img, alpha = eye_interior(frame, d68, flat)
    assert np.isfinite(img).all() and alpha[:, :48].max() == 0 and alpha[:, 50:].max() == 1
    off = p68.copy()
    off[36:48] += (-60.0, -60.0)  # both puppet eyes off the top-left of the frame
    img, alpha = eye_interior(frame, d68, off)
    assert np.isfinite(img).all() and alpha.max() == 0


def test_eye_skin_weights_cover_the_skin_under_the_lower_lids():
    """Weight 1 on the skin just under each lower lid and past its outer corner, 0 over the upper lid,
    well below the band (``below`` 0.25 eye-corner distances) and between the eyes' inner corners; the
    lash zone covers the eyeball and its lid rims, not the skin under it."""
    from facetex.puppet.eyes import eye_skin_weights

    p = _eyes68(cx=60.0, cy=40.0, half=10.0, gap=8.0, apart=40.0)
    w, eyes = eye_skin_weights(p, (100, 120))
    iod = float(np.linalg.norm(p[36] - p[45]))  # 60 px: the band is 15 px deep
    for ex, out in ((40, -1), (80, 1)):
        assert w[52, ex] == pytest.approx(1.0)  # 8 px under the lower lid (44)
        assert w[28, ex] < 0.01 and w[40 + 4 + int(0.25 * iod) + 12, ex] < 0.01
        assert w[45, ex + out * 13] > 0.9  # 3 px past the outer corner
        assert eyes[40, ex] and eyes[45, ex] and not eyes[52, ex]
    assert w[48, 60] < 0.05  # between the eyes, under the inner corners' line
    assert w.dtype == np.float32 and eyes.dtype == bool
    # another face's eyes (the driver's, 8 px lower) are left out too; the zone stays this face's
    w2, both = eye_skin_weights(p, (100, 120), other68=p + [0.0, 8.0])
    np.testing.assert_array_equal(w2, w)
    assert both[52, 40] and both[52, 80] and (both >= eyes).all()
