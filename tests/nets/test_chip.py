"""dlib-style face chips without dlib, checked against dlib."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from facetex._resources import model_path, sample_path
from facetex.errors import BadInputError
from facetex.io import read_image
from facetex.nets.chip import (
    chip_matrix_from_details,
    face_chip,
    face_chip_details,
    face_chip_matrix,
    face_chip_tensor,
)

dlib = pytest.importorskip("dlib")

FACES = ("frl_003_neutral", "frl_004_smiling", "frl_005_neutral")


@pytest.fixture(scope="module")
def faces():
    """(float image, uint8 image, dlib shape, points68) per bundled face."""
    det = dlib.get_frontal_face_detector()
    sp = dlib.shape_predictor(str(model_path("shape_predictor_68_face_landmarks.dat")))
    out = []
    for name in FACES:
        img = read_image(sample_path(name + ".jpg"))
        img8 = (img * 255 + 0.5).astype(np.uint8)
        shape = sp(img8, det(img8, 0)[0])
        pts = np.array([(p.x, p.y) for p in shape.parts()], dtype=np.float64)
        out.append((img, img8, shape, pts))
    return out


def test_chip_details_match_dlib(faces):
    for _, _, shape, pts in faces:
        ref = dlib.get_face_chip_details(shape, 150, 0.25)
        rect, angle = face_chip_details(pts, 150, 0.25)
        r = ref.rect
        np.testing.assert_allclose(rect, (r.left(), r.top(), r.right(), r.bottom()), atol=0.5)
        assert abs(angle - ref.angle) < 1e-3
        # the matrix sends the rectangle's rotated corners to the outer chip pixel centres
        m = face_chip_matrix(pts, 150, 0.25)
        c, s = np.cos(ref.angle), np.sin(ref.angle)
        cx, cy = (r.left() + r.right()) / 2, (r.top() + r.bottom()) / 2
        for (x, y), want in (((r.left(), r.top()), (0, 0)), ((r.right(), r.bottom()), (149, 149))):
            px = cx + c * (x - cx) - s * (y - cy)
            py = cy + s * (x - cx) + c * (y - cy)
            np.testing.assert_allclose(m @ [px, py, 1.0], want, atol=0.5)


def test_matrix_hand_computed():
    # an axis-aligned 300-px square centred at (200, 100): scale 149/299, centre -> 74.5
    m = chip_matrix_from_details((50.5, -49.5, 349.5, 249.5), 0.0, 150)
    k = 149 / 299
    np.testing.assert_allclose(m, [[k, 0, 74.5 - 200 * k], [0, k, 74.5 - 100 * k]], atol=1e-12)
    # 90° rotation: the image x axis becomes the chip's -y axis
    m = chip_matrix_from_details((0, 0, 149, 149), np.pi / 2, 150)
    np.testing.assert_allclose(m[:, :2], [[0, 1], [-1, 0]], atol=1e-12)


def test_face_chip_matches_dlib(faces):
    for img, img8, shape, pts in faces:
        ref = dlib.get_face_chip(img8, shape, size=150, padding=0.25).astype(np.float32) / 255
        ours = face_chip(img, pts)
        assert ours.shape == (150, 150, 3) and ours.dtype == np.float32
        assert np.abs(ours - ref)[2:-2, 2:-2].mean() < 0.003  # dlib rounds its chip to uint8


def test_face_chip_pyramid_for_large_faces(faces):
    img, img8, _, pts = faces[1]
    big8 = cv2.resize(img8, None, fx=2.5, fy=2.5, interpolation=cv2.INTER_CUBIC)
    big_pts = (pts + 0.5) * 2.5 - 0.5
    shape = dlib.full_object_detection(dlib.rectangle(0, 0, 10, 10),
                                       [dlib.point(int(round(x)), int(round(y))) for x, y in big_pts])
    big_pts = np.array([(p.x, p.y) for p in shape.parts()], dtype=np.float64)
    ref = dlib.get_face_chip(big8, shape, size=150, padding=0.25).astype(np.float32) / 255
    big = big8.astype(np.float32) / 255
    ours = face_chip(big, big_pts)
    assert np.abs(ours - ref)[2:-2, 2:-2].mean() < 0.006
    # the torch version takes the same pyramid
    t = face_chip_tensor(torch.from_numpy(big.transpose(2, 0, 1).copy())[None], face_chip_matrix(big_pts))
    np.testing.assert_allclose(t[0].numpy().transpose(1, 2, 0), ours, atol=1e-4)


def test_face_chip_tensor_matches_numpy_and_is_differentiable(faces):
    img, _, _, pts = faces[0]
    m = face_chip_matrix(pts)
    x = torch.from_numpy(img.transpose(2, 0, 1).copy())[None].requires_grad_(True)
    chip = face_chip_tensor(x, m, 150)
    assert chip.shape == (1, 3, 150, 150)
    np.testing.assert_allclose(chip[0].detach().numpy().transpose(1, 2, 0), face_chip(img, pts), atol=1e-4)
    chip.sum().backward()
    assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0
    # batch with per-image matrices
    both = face_chip_tensor(torch.cat([x, x]).detach(), np.stack([m, m]), 150)
    assert torch.allclose(both[0], both[1])


def test_bad_inputs():
    with pytest.raises(BadInputError):
        face_chip_matrix(np.zeros((5, 2)))
    with pytest.raises(BadInputError):
        face_chip(np.zeros((10,)), np.zeros((68, 2)))
