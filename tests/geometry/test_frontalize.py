"""Frontalization with the generic 3D face (Tom Hanks Sec. 5 / Hassner et al. 2015)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from facetex._resources import sample_path
from facetex.errors import BadInputError
from facetex.geometry._generic_face import (
    CANONICAL_SIZE,
    DATA_PATH,
    EYE_DISTANCE_MM,
    FLIP68,
    barycentric_lift,
    canonical_depth_from_mesh,
    canonical_frame,
    load_generic_face,
)
from facetex.geometry.frontalize import (
    PNP_INDEX,
    Frontalized,
    HeadPose,
    canonical_points68,
    estimate_head_pose,
    frontalize,
    symmetry_fill_image,
    rotate_face,
    rotation_from_angles,
)

INNER = np.arange(17, 68)


def _load(name: str) -> np.ndarray:
    bgr = cv2.imread(str(sample_path(name)), cv2.IMREAD_COLOR)
    return (bgr[..., ::-1] / 255.0).astype(np.float32)


@pytest.fixture(scope="module")
def faces():
    from facetex.landmarks import detect_face

    out = {}
    for name in ("frl_004_neutral.jpg", "frl_005_neutral.jpg"):
        img = _load(name)
        out[name] = (img, detect_face(img).points68.copy())
    return out


def _mean_dist(a, b):
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b), axis=1).mean())


# --- the generic model -------------------------------------------------------------


def test_generic_face_model_is_symmetric_metric_and_small():
    g = load_generic_face()
    assert DATA_PATH.stat().st_size < 300 * 1024
    assert g.vertices.shape == (468, 3) and g.points68.shape == (68, 3)
    assert g.triangles.min() >= 0 and g.triangles.max() < 468 and len(g.triangles) > 800
    assert "Face Research Lab London" in g.provenance and "CC BY 4.0" in g.provenance
    mirror = g.points68[FLIP68] * [-1, 1, 1]
    np.testing.assert_allclose(mirror, g.points68, atol=1e-6)
    np.testing.assert_allclose(g.vertices[g.mirror] * [-1, 1, 1], g.vertices, atol=1e-4)
    eye_r, eye_l = g.points68[36:42].mean(0), g.points68[42:48].mean(0)
    assert np.linalg.norm(eye_l - eye_r) == pytest.approx(EYE_DISTANCE_MM, rel=1e-6)
    np.testing.assert_allclose((eye_r + eye_l) / 2, 0, atol=1e-6)
    # nose tip (30) is the inner point closest to the camera; chin (8) below the mouth (57)
    assert np.argmin(g.points68[17:, 2]) + 17 == 30
    assert g.points68[8, 1] > g.points68[57, 1] > g.points68[33, 1] > g.points68[30, 1] > 0


def test_stored_depth_map_matches_mesh():
    g = load_generic_face()
    z, mask = canonical_depth_from_mesh(g.vertices, g.triangles, canonical_frame(CANONICAL_SIZE))
    assert g.depth.shape == (CANONICAL_SIZE[1], CANONICAL_SIZE[0])
    np.testing.assert_array_equal(np.isfinite(g.depth), mask)
    np.testing.assert_allclose(g.depth[mask], z[mask], atol=1e-3)


def test_barycentric_lift_hand_computed():
    v = np.array([[0, 0, 3.0], [3, 0, 6.0], [0, 3, 9.0]])
    t = np.array([[0, 1, 2]])
    p = barycentric_lift(v, t, np.array([[1.0, 1.0], [3.0, 3.0]]))
    assert p[0].tolist() == pytest.approx([1, 1, 6.0])  # centroid: mean z
    assert p[1, 2] == pytest.approx(7.5)  # off the mesh: nearest edge point (1.5, 1.5)


def test_canonical_frame_hand_computed():
    fr = canonical_frame((192, 240))
    assert fr.scale == pytest.approx(0.36 * 192 / 63)
    p = canonical_points68((192, 240))
    eye_r, eye_l = p[36:42].mean(0), p[42:48].mean(0)
    np.testing.assert_allclose(eye_r, [95.5 - 0.18 * 192, 96.0], atol=1e-6)
    np.testing.assert_allclose(eye_l, [95.5 + 0.18 * 192, 96.0], atol=1e-6)
    assert p.min() > 0 and p[:, 0].max() < 192 and p[:, 1].max() < 240


# --- pose ----------------------------------------------------------------------------


def test_rotation_angle_conventions():
    nose = np.array([0, 0, -1.0])  # towards the camera
    assert rotation_from_angles(yaw=90) @ nose == pytest.approx([1, 0, 0], abs=1e-12)  # nose to image right
    assert rotation_from_angles(pitch=90) @ nose == pytest.approx([0, 1, 0], abs=1e-12)  # nose down
    assert rotation_from_angles(roll=90) @ np.array([1, 0, 0.0]) == pytest.approx([0, 1, 0], abs=1e-12)


def _synthetic_points(yaw, pitch, roll, shape=(480, 400), dist=600.0):
    g = load_generic_face()
    h, w = shape
    f = float(max(h, w))
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])
    R = rotation_from_angles(yaw, pitch, roll)
    cam = g.points68 @ R.T + [5.0, -10.0, dist]
    pix = cam @ K.T
    return pix[:, :2] / pix[:, 2:]


@pytest.mark.parametrize("angles", [(0, 0, 0), (25, -10, 5), (-35, 8, -12)])
def test_pose_recovers_known_rotation(angles):
    pts = _synthetic_points(*angles)
    pose = estimate_head_pose(pts, (480, 400))
    assert isinstance(pose, HeadPose)
    assert (pose.yaw, pose.pitch, pose.roll) == pytest.approx(angles, abs=0.05)
    assert pose.tvec == pytest.approx([5.0, -10.0, 600.0], abs=0.5)
    assert pose.rms_px < 1e-3
    assert pose.project(load_generic_face().points68)[PNP_INDEX] == pytest.approx(pts[PNP_INDEX], abs=1e-3)


def test_pose_corrected_points_of_a_posed_generic_face_are_canonical():
    pts = _synthetic_points(30, 10, -5)
    img = np.full((480, 400, 3), 0.5, np.float32)
    fr = frontalize(img, pts)
    np.testing.assert_allclose(fr.points68, canonical_points68(), atol=0.05)


def test_pose_corrected_points68_are_frontalizes_without_the_image(faces):
    from facetex.geometry import pose_corrected_points68

    for img, pts in faces.values():
        for size in ((192, 240), (96, 120)):
            want = frontalize(img, pts, size=size).points68
            np.testing.assert_array_equal(pose_corrected_points68(img.shape, pts, size=size), want)
    with pytest.raises(BadInputError):
        pose_corrected_points68((480, 400, 3), np.zeros((5, 2)))


# --- real faces -------------------------------------------------------------------


@pytest.mark.parametrize("name", ["frl_004_neutral.jpg", "frl_005_neutral.jpg"])
def test_frontal_portrait_changes_little(faces, name):
    from facetex.landmarks import detect_face

    img, pts = faces[name]
    fr = frontalize(img, pts)
    assert abs(fr.pose.yaw) < 8 and abs(fr.pose.pitch) < 10 and abs(fr.pose.roll) < 5
    # landmarks re-detected on the frontal view sit on the pose-corrected ones
    again = detect_face(fr.image).points68
    assert _mean_dist(again[INNER], fr.points68[INNER]) < 2.0
    assert _mean_dist(again, fr.points68) < 3.0
    # identity differs from the generic face only by a few pixels
    assert _mean_dist(fr.points68, canonical_points68()) < 7.0
    # the frontal view is close to a similarity warp of the photo on the same landmarks
    a, _ = cv2.estimateAffinePartial2D(pts[INNER].astype(np.float32), fr.points68[INNER].astype(np.float32))
    sim = cv2.warpAffine(img, a, CANONICAL_SIZE)
    assert float(np.median(np.abs(sim - fr.image).mean(-1)[fr.face_mask])) < 0.03
    assert float((fr.visibility[fr.face_mask] > 0.5).mean()) > 0.9


@pytest.fixture(scope="module")
def turned(faces):
    from facetex.landmarks import detect_face

    img, pts = faces["frl_005_neutral.jpg"]
    out = {}
    for yaw in (20.0, -20.0):
        rot = rotate_face(img, pts, yaw=yaw)
        out[yaw] = (rot, detect_face(rot).points68.copy())
    return out


@pytest.mark.parametrize("yaw", [20.0, -20.0])
def test_turned_face_is_frontalized(faces, turned, yaw):
    img, pts = faces["frl_005_neutral.jpg"]
    ref = frontalize(img, pts)
    rot, rpts = turned[yaw]
    assert _mean_dist(rpts, pts) > 10  # the synthetic photo is really turned
    fr = frontalize(rot, rpts)
    assert fr.pose.yaw == pytest.approx(ref.pose.yaw + yaw, abs=4.0)
    assert abs(fr.pose.pitch - ref.pose.pitch) < 4 and abs(fr.pose.roll - ref.pose.roll) < 4
    assert _mean_dist(fr.points68[INNER], ref.points68[INNER]) < 3.0
    assert _mean_dist(fr.points68, ref.points68) < 4.0
    assert _mean_dist(fr.points68, canonical_points68()) < 7.0
    # self-occlusion: zeros on the far side only (nose to image right hides the image-right cheek)
    m, v, half = fr.face_mask, fr.visibility, CANONICAL_SIZE[0] // 2
    far, near = (slice(half, None), slice(None, half)) if yaw > 0 else (slice(None, half), slice(half, None))
    assert float((v[:, far][m[:, far]] == 0).mean()) > 0.08
    assert float((v[:, near][m[:, near]] == 0).mean()) < 0.03


def test_symmetry_fill_uses_the_mirrored_side(turned):
    rot, rpts = turned[20.0]
    plain = frontalize(rot, rpts, symmetry_fill=False)
    fill = frontalize(rot, rpts, symmetry_fill=True)
    v, vm = plain.visibility, plain.visibility[:, ::-1]
    np.testing.assert_array_equal(fill.visibility, v)
    # well inside what the photo saw: the photo itself
    inner = cv2.erode((v > 0.999).astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    np.testing.assert_allclose(fill.image[inner], plain.image[inner], atol=1e-3)
    # well inside the hidden side: the mirrored side, brightness-matched (a smooth gain near 1)
    hidden = (cv2.dilate((v > 0).astype(np.uint8), np.ones((5, 5), np.uint8)) == 0) & (vm > 0.999)
    assert hidden.sum() > 200
    gain = fill.image[hidden] / np.maximum(plain.image[:, ::-1][hidden], 1e-3)
    assert 0.7 < np.median(gain) < 1.4 and np.percentile(np.abs(gain - np.median(gain)), 90) < 0.15
    assert np.abs(fill.image[hidden] - plain.image[hidden]).mean() > 0.01


def test_symmetry_fill_matches_brightness_without_a_seam():
    # a face lit from its left: its right half is brighter (0.5 against 0.3); the right quarter is
    # unseen. Filled from the darker left half as it is, it would step down from 0.5 to 0.3 at the
    # edge of what was seen; gain-matched and feathered, the row stays smooth and bright
    H, W = 240, 192
    img = np.full((H, W, 3), 0.3, np.float32)
    img[:, W // 2:] = 0.5
    vis = np.ones((H, W), np.float32)
    vis[:, 144:] = 0
    out = symmetry_fill_image(img, vis)
    row = out[120, :, 0]
    assert np.abs(np.diff(row[100:])).max() < 0.02  # no seam where own meets mirrored
    assert row[170] > 0.42 and abs(row[170] - 0.3) > 0.1  # not the plain (darker) mirror
    np.testing.assert_allclose(row[:80], 0.3, atol=1e-5)  # the seen side, far from the edge, untouched


def test_symmetry_fill_closes_narrow_bands_neither_side_saw():
    """A 6 px band at a turned cheek's edge that neither side saw keeps the photo's raw sample (its
    silhouette: bright background, 1.0); it takes its surroundings' fill (0.4) instead. A wide area
    nobody saw (the top rows: hair, background) keeps its raw sample; outside ``region`` nothing
    changes."""
    H, W = 240, 192
    img = np.full((H, W, 3), 0.4, np.float32)
    vis = np.ones((H, W), np.float32)
    vis[:, 20:26] = 0
    vis[:, W - 26:W - 20] = 0  # the mirrored band: hidden too
    img[:, 20:26] = 1.0
    vis[:40] = 0
    img[:40] = 0.9
    out = symmetry_fill_image(img, vis)
    np.testing.assert_allclose(out[80:200, 20:26], 0.4, atol=0.02)
    np.testing.assert_allclose(out[:10], 0.9, atol=1e-5)  # far from anything seen: as sampled
    kept = symmetry_fill_image(img, vis, np.zeros((H, W), bool))
    np.testing.assert_allclose(kept[80:200, 20:26], 1.0, atol=1e-5)


def test_outputs_shapes_dtypes_and_map(faces):
    img, pts = faces["frl_004_neutral.jpg"]
    fr = frontalize(img, pts, size=(200, 250), symmetry_fill=False)
    assert isinstance(fr, Frontalized)
    assert fr.image.shape == (250, 200, 3) and fr.image.dtype == np.float32
    assert fr.visibility.shape == (250, 200) and fr.visibility.dtype == np.float32
    assert fr.visibility.min() >= 0 and fr.visibility.max() <= 1
    assert fr.map.shape == (250, 200, 2) and fr.map.dtype == np.float32
    assert fr.points68.shape == (68, 2) and fr.points68.dtype == np.float64
    assert fr.face_mask.shape == (250, 200) and fr.face_mask.dtype == bool
    assert 0 <= fr.image.min() and fr.image.max() <= 1
    # the map frontalizes other images of the same photo the same way (no shrinking at this scale)
    np.testing.assert_allclose(fr.warp(img), fr.image, atol=1e-6)
    mask = np.zeros(img.shape[:2], np.float32)
    mask[:, : img.shape[1] // 2] = 1
    assert fr.warp(mask).shape == (250, 200)
    # the map sends the pose-corrected eye corners close to the detected ones
    for i in (36, 45, 30):
        u, v = fr.points68[i]
        x, y = fr.map[int(round(v)), int(round(u))]
        assert math.hypot(x - pts[i, 0], y - pts[i, 1]) < 4.0
    # uint8 input is accepted
    fr8 = frontalize((img * 255).astype(np.uint8), pts, symmetry_fill=False)
    assert fr8.image.dtype == np.float32 and fr8.image.shape == (240, 192, 3)


@pytest.mark.parametrize(
    "points",
    [np.zeros((67, 2)), np.zeros((68, 3)), np.full((68, 2), np.nan), np.zeros((68, 2)), "points"],
)
def test_bad_points_raise(points):
    img = np.zeros((100, 100, 3), np.float32)
    with pytest.raises(BadInputError):
        frontalize(img, points)


def test_bad_image_size_and_focal_raise():
    pts = _synthetic_points(0, 0, 0)
    with pytest.raises(BadInputError):
        frontalize(np.zeros((480, 400), np.float32), pts)
    with pytest.raises(BadInputError):
        frontalize(np.zeros((480, 400, 3), np.int32), pts)
    with pytest.raises(BadInputError):
        frontalize(np.zeros((480, 400, 3), np.float32), pts, size=(0, 10))
    with pytest.raises(BadInputError):
        estimate_head_pose(pts, (480, 400), focal=-1)
    with pytest.raises(BadInputError):
        estimate_head_pose(pts, "shape")


def test_fill_confidence_hand_computed():
    from facetex.geometry.frontalize import fill_confidence

    H, W = 240, 192
    vis = np.zeros((H, W), np.float32)
    vis[:, : W // 2 - 20] = 1.0  # the left part seen, its mirror (the right part) not
    c = fill_confidence(vis, mirror_weight=0.1, floor=0.02, feather=2.0)
    assert c[100, 10] == pytest.approx(1.02, abs=1e-4)  # seen: 1 + floor
    assert c[100, W - 11] == pytest.approx(0.1 + 0.02, abs=1e-4)  # mirror-filled: 0.1 + floor
    assert c[100, W // 2] == pytest.approx(0.02, abs=1e-4)  # neither: the floor
    assert np.abs(np.diff(c[100])).max() < 0.25  # feathered: no hard edge
    # outside the photo's own face outline the trust drops to 0.25 of it
    pts = canonical_points68((W, H))
    cf = fill_confidence(np.ones((H, W), np.float32), pts, outside_face=0.25, floor=0.0)
    assert cf[5, 5] == pytest.approx(0.25, abs=1e-3) and cf[120, 96] == pytest.approx(1.0, abs=1e-3)
    # uint8 visibility (as stored in a persona) and a batch of maps
    assert fill_confidence(np.stack([(vis * 255).astype(np.uint8)] * 2)).shape == (2, H, W)
