"""facetex.landmarks on the bundled FRL portraits (400x400, one frontal face each)."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from facetex._resources import sample_path
from facetex.errors import BadInputError, NoFaceError
from facetex.io import read_image
from facetex.landmarks import (
    POINTS49_INDEX,
    POINTS66_INDEX,
    Face,
    detect_face,
    detect_faces,
    face_mesh468,
    landmarks_in_box,
    points49,
    points66,
)

SAMPLES = ["frl_003_neutral", "frl_004_neutral", "frl_004_smiling", "frl_005_neutral",
           "frl_005_smiling", "frl_008_neutral"]


@pytest.fixture(scope="module")
def images():
    return {n: read_image(sample_path(n + ".jpg")) for n in SAMPLES}


@pytest.fixture(scope="module")
def faces(images):
    return {n: detect_faces(im) for n, im in images.items()}


def test_subset_indices():
    assert len(POINTS66_INDEX) == 66 and len(POINTS49_INDEX) == 49
    assert 60 not in POINTS66_INDEX and 64 not in POINTS66_INDEX
    assert set(range(68)) - set(POINTS66_INDEX) == {60, 64}
    assert set(range(68)) - set(POINTS49_INDEX) == set(range(17)) | {60, 64}
    assert list(POINTS49_INDEX[:3]) == [17, 18, 19] and POINTS49_INDEX[-1] == 67
    assert np.all(np.diff(POINTS66_INDEX) > 0) and np.all(np.diff(POINTS49_INDEX) > 0)
    with pytest.raises(ValueError):
        POINTS66_INDEX[0] = 5  # read-only module constant
    p = np.arange(136, dtype=float).reshape(68, 2)
    assert points66(p).shape == (66, 2) and points49(p).shape == (49, 2)
    assert points66(p)[60].tolist() == p[61].tolist()  # 60 skipped
    assert points49(p)[0].tolist() == p[17].tolist()
    assert points49(p)[43].tolist() == p[61].tolist()  # 17..59 are 43 points, then 61
    with pytest.raises(BadInputError):
        points66(p[:66])


def test_face_dataclass_and_scaled():
    p = np.zeros((68, 2))
    p[10] = (3.0, 7.0)
    f = Face((1, 2, 11, 22), p, 0.5)
    with pytest.raises(dataclasses.FrozenInstanceError):
        f.score = 1.0
    assert not f.points68.flags.writeable
    p[10] = (0, 0)  # the Face keeps its own copy
    assert f.points68[10].tolist() == [3.0, 7.0]
    g = f.scaled(2.0)
    # pixel centres at integers: x' = (x + 0.5) * 2 - 0.5
    assert g.points68[10].tolist() == [6.5, 14.5]
    assert g.box == (2.5, 4.5, 22.5, 44.5)
    assert g.score == 0.5
    assert np.allclose(g.scaled(0.5).points68, f.points68)
    assert f.points66.shape == (66, 2) and f.points49.shape == (49, 2)


def test_one_face_points_inside_box_and_ordered(faces):
    for name, fs in faces.items():
        assert len(fs) == 1, name
        f = fs[0]
        p = f.points68
        x0, y0, x1, y1 = f.box
        assert x1 - x0 > 80 and y1 - y0 > 80
        # brows, eyes, nose, mouth: inside the detector box
        inner = f.points49
        assert np.all((inner[:, 0] >= x0) & (inner[:, 0] <= x1) & (inner[:, 1] >= y0) & (inner[:, 1] <= y1)), name
        # the jaw may overhang dlib's tight box a little (the chin mostly), not more than 25 %
        m = 0.25 * (x1 - x0)
        assert np.all((p[:, 0] >= x0 - m) & (p[:, 0] <= x1 + m) & (p[:, 1] >= y0 - m) & (p[:, 1] <= y1 + m)), name
        right_eye, left_eye = p[36:42].mean(0), p[42:48].mean(0)  # subject's right eye is image-left
        nose_tip, mouth = p[30], p[48:60].mean(0)
        assert right_eye[0] + 30 < left_eye[0]
        assert max(right_eye[1], left_eye[1]) < nose_tip[1] < mouth[1] < p[8][1]  # eyes, nose, mouth, chin
        assert right_eye[0] < nose_tip[0] < left_eye[0]
        assert p[0][0] < p[16][0] and p[48][0] < p[54][0] and p[36][0] < p[39][0] < p[42][0] < p[45][0]
        assert np.all(p[19:25, 1].mean() < p[36:48, 1].min())  # brows above the eyes


def test_uint8_and_float_inputs_agree(images, faces):
    im = images["frl_004_neutral"]
    f8 = detect_faces(np.round(im * 255).astype(np.uint8))[0]
    assert f8.box == faces["frl_004_neutral"][0].box
    assert np.array_equal(f8.points68, faces["frl_004_neutral"][0].points68)


def test_landmarks_in_known_box_match_detection(images, faces):
    f = faces["frl_005_smiling"][0]
    p = landmarks_in_box(images["frl_005_smiling"], f.box)
    assert p.shape == (68, 2) and p.dtype == np.float64
    assert np.abs(p - f.points68).max() <= 1.0
    with pytest.raises(BadInputError):
        landmarks_in_box(images["frl_005_smiling"], (10, 10, 5, 20))


def test_two_faces_largest_first_and_face_index(images):
    big = images["frl_004_neutral"]
    small = cv2.resize(images["frl_003_neutral"], (300, 300), interpolation=cv2.INTER_AREA)
    canvas = np.ones((400, 700, 3), np.float32)
    canvas[:, :400] = big
    canvas[50:350, 400:] = small
    fs = detect_faces(canvas)
    assert len(fs) == 2
    assert fs[0].area > fs[1].area
    assert fs[0].box[2] < 400 <= fs[1].box[0]  # the larger face is the left (400 px) one
    assert detect_face(canvas, face_index=1).box == fs[1].box
    assert detect_face(canvas).box == fs[0].box
    with pytest.raises(BadInputError, match="2 face"):
        detect_face(canvas, face_index=2, source="pair.png")


def test_no_face_names_source():
    flat = np.full((200, 240, 3), 0.5, np.float32)
    assert detect_faces(flat) == []
    with pytest.raises(NoFaceError) as e:
        detect_face(flat, source="blank.png")
    assert e.value.path == "blank.png" and "blank.png" in str(e.value)
    assert "\n" not in str(e.value)


def test_bad_input_arrays():
    with pytest.raises(BadInputError):
        detect_faces(np.zeros((10, 10, 5), np.float32))
    with pytest.raises(BadInputError):
        detect_faces(np.zeros((50, 50, 3), np.float32), detector="haar")
    with pytest.raises(BadInputError):
        detect_faces(np.zeros((50, 50, 3), np.float32), upsample=-1)


MESH_DLIB = [(33, 36), (263, 45), (61, 48), (291, 54)]  # outer eye corners, mouth corners


def test_mesh468_corners_agree_with_dlib(images, faces):
    errs = []
    for name in SAMPLES:
        f = faces[name][0]
        mesh, score = face_mesh468(images[name], f, return_score=True)
        assert mesh.shape == (468, 3) and mesh.dtype == np.float64
        assert score > 0.9
        errs.append([np.linalg.norm(mesh[a, :2] - f.points68[b]) for a, b in MESH_DLIB])
        assert mesh[1, 2] < np.median(mesh[:, 2])  # nose tip (1) is closer than most of the face
    errs = np.array(errs)
    # annotation conventions differ by ~2 px at this size (eye distance ~70 px)
    assert errs.mean() < 3.0, errs
    assert errs.max() < 5.0, errs


def test_mesh468_follows_in_plane_rotation(images, faces):
    im, f = images["frl_008_neutral"], faces["frl_008_neutral"][0]
    mesh = face_mesh468(im, f)
    R = cv2.getRotationMatrix2D((200.0, 200.0), 20.0, 1.0)  # 20 deg; maps pixel centres
    rot = cv2.warpAffine(im, R, (400, 400), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    p_rot = f.points68 @ R[:, :2].T + R[:, 2]
    mesh_rot = face_mesh468(rot, p_rot)  # accepts plain (68, 2) points
    expected = mesh[:, :2] @ R[:, :2].T + R[:, 2]
    err = np.linalg.norm(mesh_rot[:, :2] - expected, axis=1)
    assert np.median(err) < 2.0 and err.max() < 6.0


def test_mesh468_rejects_non_face(images, faces):
    f = faces["frl_004_neutral"][0]
    with pytest.raises(NoFaceError) as e:
        face_mesh468(np.full((400, 400, 3), 0.5, np.float32), f, source="flat.png")
    assert e.value.path == "flat.png"


def test_cnn_detector_agrees_with_hog(images, faces):
    im = images["frl_004_neutral"][90:310, 90:310]  # a crop around the face keeps the CNN fast
    hog = faces["frl_004_neutral"][0].points68 - 90
    fs = detect_faces(im, detector="cnn")
    assert len(fs) == 1
    assert np.linalg.norm(fs[0].points68 - hog, axis=1).mean() < 2.0


def test_frontal_detector_cached_file_detects_the_same(tmp_path, monkeypatch):
    import dlib

    from facetex.landmarks import _frontal_face_detector

    monkeypatch.setenv("FACETEX_CACHE", str(tmp_path / "cache"))
    img = (read_image(sample_path("frl_004_smiling.jpg")) * 255 + 0.5).astype(np.uint8)

    def boxes(det):
        rects, scores, kinds = det.run(img, 0, 0.0)
        return [(r.left(), r.top(), r.right(), r.bottom()) for r in rects], list(scores), list(kinds)

    want = boxes(dlib.get_frontal_face_detector())
    assert want[0]
    first = _frontal_face_detector()  # built, then saved
    saved = list((tmp_path / "cache").glob("dlib-*-frontal_face_detector.svm"))
    assert len(saved) == 1 and boxes(first) == want
    assert boxes(_frontal_face_detector()) == want  # loaded from the file
    saved[0].write_bytes(b"damaged")
    assert boxes(_frontal_face_detector()) == want and saved[0].stat().st_size > 1000  # built and saved again
    monkeypatch.setenv("FACETEX_CACHE", str(saved[0]))  # a file, not a folder: nothing saved, still works
    assert boxes(_frontal_face_detector()) == want


def test_eye_centres_and_distance_by_hand():
    """Eye points 36-41 around (1, 2), 42-47 around (4, 6): centres (1, 2) and (4, 6), distance 5;
    a stack of faces (the second twice the size) gives one distance per face."""
    from facetex.landmarks import eye_centres, eye_distance

    p = np.zeros((68, 2))
    ring = np.array([[-1, 0], [1, 0], [0, 1], [0, -1], [2, 2], [-2, -2]], float)
    p[36:42] = ring + [1, 2]
    p[42:48] = ring + [4, 6]
    a, b = eye_centres(p)
    np.testing.assert_allclose(a, [1, 2])
    np.testing.assert_allclose(b, [4, 6])
    assert eye_distance(p) == pytest.approx(5.0) and isinstance(eye_distance(p), float)
    np.testing.assert_allclose(eye_distance(np.stack([p, 2 * p])), [5.0, 10.0])
