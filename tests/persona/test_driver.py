"""Driver motion: Procrustes, filling, smoothing, mouth opening, tracking a synthetic video."""

from __future__ import annotations

import numpy as np
import pytest

from facetex.errors import NoFaceError
from facetex.io import write_video
from facetex.persona.driver import (
    GridInterpolator,
    driver_motion,
    fill_lost,
    generalized_procrustes,
    mouth_opening,
    similarity_procrustes,
    smooth_series,
    track_driver,
)


def _rot(ax, ay, az):
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("xyz", [ax, ay, az]).as_matrix()


def test_similarity_procrustes_recovers_transform():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(30, 3))
    R = _rot(0.3, -0.2, 0.5)
    b = 2.5 * a @ R.T + np.array([1.0, -2.0, 3.0])
    s, r, t = similarity_procrustes(a, b)
    assert s == pytest.approx(2.5)
    np.testing.assert_allclose(r, R, atol=1e-9)
    np.testing.assert_allclose(t, [1.0, -2.0, 3.0], atol=1e-9)
    # a reflection is never returned
    s, r, t = similarity_procrustes(a, a * [1, 1, -1])
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_generalized_procrustes_separates_pose_from_shape():
    rng = np.random.default_rng(2)
    base = rng.normal(size=(40, 3))
    meshes = []
    for i in range(6):
        m = base.copy()
        m[0] += [0, 0.1 * i, 0]  # one vertex moves (expression)
        meshes.append(1.5 * m @ _rot(0.1 * i, 0.05 * i, -0.1 * i).T + i)
    mean, s, R, t = generalized_procrustes(np.array(meshes))
    for i in range(6):
        aligned = (meshes[i] - t[i]) @ R[i] / s[i]
        # everything but the moving vertex is explained by the rigid part
        assert np.abs(aligned[1:] - mean[1:]).max() < 0.05
    moved = [((meshes[i] - t[i]) @ R[i] / s[i])[0, 1] for i in range(6)]
    assert np.all(np.diff(moved) > 0)


def test_fill_lost_interpolates_and_holds():
    x = np.array([np.nan, 1.0, np.nan, np.nan, 4.0, np.nan])
    found = np.isfinite(x)
    np.testing.assert_allclose(fill_lost(x, found), [1, 1, 2, 3, 4, 4])


def test_smoothing_removes_jitter_without_lag():
    t = np.arange(60, dtype=float)
    clean = np.sin(t / 4.0)
    noisy = clean + np.random.default_rng(0).normal(scale=0.05, size=t.size)
    sm = smooth_series(noisy, 5, 2)
    assert np.abs(sm - clean).mean() < 0.85 * np.abs(noisy - clean).mean()  # SG(5, 2) noise gain: std x 0.70
    # zero phase: the peak of a pulse stays at its frame
    pulse = np.exp(-((t - 30) ** 2) / 8.0)
    assert int(np.argmax(smooth_series(pulse, 5, 2))) == 30


@pytest.mark.parametrize("n, window, order", [(60, 5, 2), (7, 5, 2), (30, 9, 3), (5, 7, 2), (12, 6, 2)])
def test_smoothing_matches_scipy_savgol(n, window, order):
    from scipy.signal import savgol_filter

    x = np.random.default_rng(n).normal(size=(n, 3, 2))
    w = min(window, n)
    w -= 1 - w % 2
    np.testing.assert_allclose(smooth_series(x, window, order), savgol_filter(x, w, order, axis=0, mode="interp"),
                               atol=1e-12)


def test_mouth_opening_hand_computed():
    p = np.zeros((68, 2))
    p[36], p[45] = [0, 0], [100, 0]
    for u, l in zip((61, 62, 63), (67, 66, 65)):
        p[u], p[l] = [50, 100], [50, 110]
    assert mouth_opening(p) == pytest.approx(0.1)


def test_grid_interpolator_is_linear():
    xy = np.array([[0, 0], [10, 0], [0, 10], [10, 10]], float)
    gy, gx = np.mgrid[0:12, 0:12].astype(float)
    g = GridInterpolator(xy, np.stack([gx, gy], -1))
    v = 2 * xy[:, 0] + 3 * xy[:, 1] + 1
    out = g(v)
    assert g.mask[5, 5] and not g.mask[11, 11]
    np.testing.assert_allclose(out[g.mask], (2 * gx + 3 * gy + 1)[g.mask], atol=1e-9)


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    from test_puppet import N_BLANK, N_MORPH, morph_frames  # same folder (rootdir-less import)

    path = tmp_path_factory.mktemp("drv") / "drv.mp4"
    write_video(path, morph_frames(), fps=10)
    return track_driver(path), N_MORPH, N_BLANK


def test_track_counts_lost_frames(tracked):
    tr, n_morph, n_blank = tracked
    assert tr.n_frames == n_morph + n_blank + 2
    assert tr.n_lost == n_blank
    assert not tr.found[n_morph : n_morph + n_blank].any()
    assert tr.frontal.shape[1:] == (240, 192, 3)


def test_mouth_opening_follows_neutral_to_smiling(tracked):
    tr, n_morph, _ = tracked
    m = driver_motion(tr)
    op = m.opening[:n_morph]
    assert op[-1] > op[0] + 0.04
    assert np.corrcoef(op, np.arange(n_morph))[0, 1] > 0.7
    # the non-rigid field moves the mouth: the lower lip's vertices move down in the smiling frames
    d = m.delta_field(n_morph - 1)
    assert d.shape == (120, 96, 3) and np.isfinite(d).all()
    lower_lip = m.fiducials[n_morph - 1, 47] - m.fiducials[0, 47]  # iBUG 66 (inner lower lip)
    assert lower_lip[1] > 1.0
    # lost frames are interpolated, not NaN
    assert np.isfinite(m.pose_A).all() and np.isfinite(m.deltas).all()


def test_video_without_face_raises(tmp_path):
    p = tmp_path / "noface.mp4"
    write_video(p, [np.full((64, 64, 3), 0.5, np.float32)] * 2, fps=5)
    with pytest.raises(NoFaceError) as e:
        track_driver(p)
    assert e.value.path == str(p)
