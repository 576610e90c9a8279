"""dlib's landmarks fitted for expression (facetex._landmark_fit): upscaled small faces, a dark face's
mouth at a normalised exposure; the persona's photos read as the driver's frames."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facetex._landmark_fit import exposure_gain, fit_landmarks


def test_fit_landmarks_on_a_small_face_is_closer_to_the_large_face_fit():
    """A ~90 px face: fitted on a 2x upscale, dlib's landmarks land nearer to those fitted on the
    same photo at 400 px than when fitted on the small frame's own pixels."""
    from facetex._resources import sample_path
    from facetex.io import read_image
    from facetex.landmarks import detect_faces, landmarks_in_box

    native, fitted = [], []
    for name in ("frl_003_neutral", "frl_004_smiling", "frl_005_neutral", "frl_008_neutral"):
        img = read_image(sample_path(f"{name}.jpg"))
        big = detect_faces(img)[0]
        s = 90.0 / (big.box[2] - big.box[0])
        small = cv2.resize(img, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
        face = detect_faces(small, upsample=1)[0]
        ref = (big.points68 + 0.5) * s - 0.5
        native.append(np.linalg.norm(landmarks_in_box(small, face.box) - ref, axis=1).mean())
        p = fit_landmarks(small, face.box, face_px=200.0)
        assert p.shape == (68, 2)
        fitted.append(np.linalg.norm(p - ref, axis=1).mean())
    assert np.mean(fitted) < 0.85 * np.mean(native) and max(fitted) < 0.8
    # a face already larger than face_px: the detector's own landmarks, untouched but for the mouth's
    # refit at a normalised exposure (this photo's face is darker than EXPOSED_FACE_LUMA)
    q = fit_landmarks(img, big.box, face_px=100.0, points68=big.points68)
    np.testing.assert_array_equal(q[:48], big.points68[:48])
    assert np.abs(q[48:] - big.points68[48:]).max() <= 2.0
    # a box at the frame's edge: the upscaled neighbourhood is clipped, the points stay in frame px
    edge = fit_landmarks(small[:, int(face.box[0]) - 2 :], np.subtract(face.box, [face.box[0] - 2, 0] * 2))
    assert np.isfinite(edge).all() and abs(edge[:, 0].min() - (p[:, 0].min() - face.box[0] + 2)) < 3


def test_exposure_gain_by_hand():
    """A grey face box of sRGB 0.2: the linear-light gain to luma 0.55 is
    ((0.605 / 1.055) ** 2.4) / ((0.255 / 1.055) ** 2.4) = 0.26328 / 0.033105 = 7.953; only the box's
    middle 60 % counts; a lighter face gets none."""
    img = np.full((100, 100, 3), 0.2, np.float32)
    assert exposure_gain(img, (0, 0, 100, 100)) == pytest.approx(7.953, rel=1e-3)
    assert exposure_gain((img * 255).round().astype(np.uint8), (0, 0, 100, 100)) == pytest.approx(7.953, rel=2e-2)
    img[:, :18] = img[:, 82:] = 1.0  # a bright border outside the middle 60 %
    assert exposure_gain(img, (0, 0, 100, 100)) == pytest.approx(7.953, rel=1e-3)
    assert exposure_gain(np.full((100, 100, 3), 0.6, np.float32), (0, 0, 100, 100)) == 1.0
    assert exposure_gain(img, (10, 10, 12, 12)) == 1.0  # too small a box to measure


def test_fit_landmarks_reads_a_dark_faces_mouth_at_a_normalised_exposure(monkeypatch):
    """A face darkened by an exposure change (x 0.08 in linear light): its mouth points, refitted on
    the frame brought back to a normal exposure, land nearer to the bright frame's than the plain
    fit's; every other point is the plain fit's."""
    import facetex._landmark_fit as fit
    from facetex._resources import sample_path
    from facetex.io import read_image
    from facetex.landmarks import detect_faces

    def lin(x):
        return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)

    def srgb(x):
        return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.clip(x, 0, None), 1 / 2.4) - 0.055)

    exposed, plain = [], []
    for name in ("frl_004_smiling", "frl_005_smiling", "frl_003_neutral"):
        img = read_image(sample_path(f"{name}.jpg"))
        big = detect_faces(img)[0]
        s = 100.0 / (big.box[2] - big.box[0])
        small = cv2.resize(img, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
        box = detect_faces(small, upsample=1)[0].box
        dark = (np.round(srgb(lin(small) * 0.08) * 255) / 255).astype(np.float32)
        ref = fit_landmarks(small, box)
        p = fit_landmarks(dark, box)
        with monkeypatch.context() as m:
            m.setattr(fit, "MIN_EXPOSURE_GAIN", np.inf)
            q = fit_landmarks(dark, box)
        np.testing.assert_array_equal(p[:48], q[:48])
        exposed.append(np.linalg.norm(p[48:] - ref[48:], axis=1).mean())
        plain.append(np.linalg.norm(q[48:] - ref[48:], axis=1).mean())
    assert np.mean(exposed) < 0.5 * np.mean(plain) and max(exposed) < 0.5


def test_refine_landmarks_refits_in_the_carried_box_and_exposes_the_mouth_once(monkeypatch):
    """refits 0 is the detection fit itself; each refit fits again in the box the points carry (a
    different box, so other points); a dark face's mouth is refitted at a normalised exposure once,
    on the last fit (not with exposure=False: then only the mouth differs)."""
    import facetex._landmark_fit as fit
    from facetex._resources import sample_path
    from facetex.io import read_image
    from facetex.landmarks import detect_faces

    img = read_image(sample_path("frl_004_smiling.jpg"))
    small = cv2.resize(img, None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA) * np.float32(0.3)
    face = detect_faces(small, upsample=1)[0]
    assert fit.exposure_gain(small, face.box) >= fit.MIN_EXPOSURE_GAIN  # dark enough to refit
    calls = []
    real = fit._mouth_exposed
    monkeypatch.setattr(fit, "_mouth_exposed", lambda *a: calls.append(1) or real(*a))
    p0 = fit.refine_landmarks(small, face.box, face.points68, refits=0)
    np.testing.assert_array_equal(p0, fit.fit_landmarks(small, face.box, points68=face.points68))
    calls.clear()
    p1 = fit.refine_landmarks(small, face.box, face.points68, refits=2)
    assert len(calls) == 1 and p1.shape == (68, 2) and np.isfinite(p1).all()
    calls.clear()
    plain = fit.refine_landmarks(small, face.box, face.points68, refits=2, exposure=False)
    assert not calls and np.abs(plain - p1)[48:].max() > 0 and np.array_equal(plain[:48], p1[:48])
    assert 0 < np.abs(p1 - p0).max() < 5.0
    box = fit.carried_box(p0 + [3.0, -2.0], face.box, p0)  # points moved: the box moves with them
    np.testing.assert_allclose(np.subtract(box, face.box), [3, -2, 3, -2], atol=1e-9)


def test_mirror_averaged_fit_commutes_with_a_flip_and_keeps_the_points_near_the_fit():
    """The mirror-averaged fit of a flipped photo is the flipped fit of the photo (points swapped
    left-right, x -> w - 1 - x), exactly for an integer box; the average stays within a pixel or two
    of the plain fit, and differs from it (dlib is not mirror-symmetric)."""
    from facetex._landmark_fit import mirror_averaged
    from facetex._resources import sample_path
    from facetex.geometry._generic_face import FLIP68
    from facetex.io import read_image
    from facetex.landmarks import detect_faces, landmarks_in_box

    img = read_image(sample_path("frl_004_smiling.jpg"))
    s = 150.0 / (detect_faces(img)[0].box[2] - detect_faces(img)[0].box[0])
    img = cv2.resize(img, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
    box = tuple(float(round(v)) for v in detect_faces(img, upsample=1)[0].box)
    w = img.shape[1]
    flipped, fbox = np.ascontiguousarray(img[:, ::-1]), (w - 1 - box[2], box[1], w - 1 - box[0], box[3])
    p = landmarks_in_box(img, box)
    a = mirror_averaged(img, box, p, exposure=False)
    b = mirror_averaged(flipped, fbox, landmarks_in_box(flipped, fbox), exposure=False)
    back = b[FLIP68].copy()
    back[:, 0] = w - 1 - back[:, 0]
    np.testing.assert_allclose(back, a, atol=1e-9)
    d = np.linalg.norm(a - p, axis=1)
    assert 0.05 < d.mean() < 1.5
    # through fit_landmarks (upscaled crop) the mirror fit is the one averaged in
    m = fit_landmarks(img, box, face_px=300.0, exposure=False, mirror=True)
    q = fit_landmarks(img, box, face_px=300.0, exposure=False)
    assert 0.05 < np.linalg.norm(m - q, axis=1).mean() < 1.5



def test_refine_landmarks_with_mirror_is_the_same_on_a_mirrored_photo():
    """``refine_landmarks(mirror=True)`` averages the refinement of the photo and of its mirror
    image: given the mirrored photo (box and points mirrored) it returns the mirrored result, and it
    differs from the plain refinement by a fraction of a pixel or two."""
    from facetex._landmark_fit import refine_landmarks
    from facetex._resources import sample_path
    from facetex.geometry._generic_face import FLIP68
    from facetex.io import read_image
    from facetex.landmarks import detect_faces

    img = read_image(sample_path("frl_005_neutral.jpg"))
    s = 100.0 / (detect_faces(img)[0].box[2] - detect_faces(img)[0].box[0])
    img = cv2.resize(img, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
    face = detect_faces(img, upsample=1)[0]
    w = img.shape[1]
    b = face.box
    fb = (w - 1 - b[2], b[1], w - 1 - b[0], b[3])
    fp = face.points68[FLIP68].copy()
    fp[:, 0] = w - 1 - fp[:, 0]
    m = refine_landmarks(img, b, face.points68, exposure=False, mirror=True)
    fm = refine_landmarks(np.ascontiguousarray(img[:, ::-1]), fb, fp, exposure=False, mirror=True)[FLIP68]
    fm[:, 0] = w - 1 - fm[:, 0]
    np.testing.assert_allclose(fm, m, atol=1e-6)
    plain = refine_landmarks(img, b, face.points68, exposure=False)
    assert 0.05 < np.linalg.norm(m - plain, axis=1).mean() < 1.5


def test_jittered_landmarks_commute_with_a_flip_ignore_far_pixels_and_stay_near_one_fit():
    """The median of the jittered, mirror-averaged fits: the same (flipped) on the mirrored photo
    (the jitters are left-right symmetric), the same on a photo with a wide border (only a crop
    round the box is read), within a pixel or two of a single fit, and a dark face's mouth read on
    the brightened copy (its points move, the eyes' do not)."""
    from facetex._landmark_fit import jittered_landmarks
    from facetex._resources import sample_path
    from facetex.geometry._generic_face import FLIP68
    from facetex.io import read_image
    from facetex.landmarks import detect_faces, landmarks_in_box

    img = read_image(sample_path("frl_004_smiling.jpg"))
    s = 200.0 / (detect_faces(img)[0].box[2] - detect_faces(img)[0].box[0])
    img = cv2.resize(img, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
    box = tuple(float(round(v)) for v in detect_faces(img, upsample=1)[0].box)
    w = img.shape[1]
    a = jittered_landmarks(img, box, exposure=False)
    flipped, fbox = np.ascontiguousarray(img[:, ::-1]), (w - 1 - box[2], box[1], w - 1 - box[0], box[3])
    back = jittered_landmarks(flipped, fbox, exposure=False)[FLIP68].copy()
    back[:, 0] = w - 1 - back[:, 0]
    np.testing.assert_allclose(back, a, atol=1e-9)
    big = cv2.copyMakeBorder(img, 300, 300, 300, 300, cv2.BORDER_CONSTANT, value=(0, 0, 0))
    shifted = jittered_landmarks(big, np.add(box, 300), exposure=False) - 300
    np.testing.assert_allclose(shifted, a, atol=1e-9)
    d = np.linalg.norm(a - landmarks_in_box(img, box), axis=1)
    assert 0.05 < d.mean() < 2.0
    dark = np.asarray(img, np.float32) * 0.25
    assert exposure_gain(dark, box) > 1.05
    plain, exposed = jittered_landmarks(dark, box, exposure=False), jittered_landmarks(dark, box)
    np.testing.assert_allclose(exposed[:48], plain[:48], atol=1e-9)
    assert np.abs(exposed[48:] - plain[48:]).max() > 0
    with pytest.raises(ValueError, match="face box"):
        jittered_landmarks(img, (10, 10, 5, 20))
