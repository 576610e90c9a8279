"""Driver motion: Procrustes, filling, smoothing, mouth opening, tracking a synthetic video."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facetex.geometry.glasses import rims_present
from facetex.errors import NoFaceError
from facetex.io import write_video
from facetex.puppet.driver import (
    DriverParams,
    GridInterpolator,
    fill_lost,
    generalized_procrustes,
    mouth_opening,
    shot_starts,
    similarity_procrustes,
    smooth_series,
    track_driver,
)
from facetex.puppet.motion import driver_motion


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


def _face(dx=0.0, scale=1.0):
    """68 points: eye corners 36/45 10 px apart, the other points spread round them, shifted by dx."""
    p = np.random.default_rng(1).normal(scale=3.0, size=(68, 2))
    p[36], p[45] = [0.0, 0.0], [10.0, 0.0]
    return p * scale + [dx, 0.0]


def test_shot_starts_at_a_jump_of_the_rigid_points():
    frames = [_face(0.05 * k) for k in range(5)]  # 0.005 eye distances a frame: a moving head
    frames += [_face(30.0 + 0.05 * k) for k in range(5)]  # 3 eye distances away: a cut
    p = np.stack(frames)
    p[6] = np.nan  # a lost frame after the cut: the next found one is compared with frame 5
    found = np.isfinite(p[:, 0, 0])
    assert np.flatnonzero(shot_starts(p, found)).tolist() == [5]
    moving_mouth = p[:5].copy()
    moving_mouth[3, 48:68] += 8.0  # lips move 0.8 eye distances: an expression, not a cut
    assert not shot_starts(moving_mouth, np.ones(5, bool)).any()
    assert not shot_starts(p[:1], np.ones(1, bool)).any()
    slip = np.stack([_face(30.0 if k == 2 else 0.0) for k in range(5)])  # one frame off, then back
    assert not shot_starts(slip, np.ones(5, bool)).any()
    assert np.flatnonzero(shot_starts(slip[:3], np.ones(3, bool))).tolist() == [2]  # the last frame: a cut
    fast = np.stack([_face(0.9 * k) for k in range(5)])  # 0.09 eye distances a frame: fast, still one shot
    assert not shot_starts(fast, np.ones(5, bool)).any()
    assert shot_starts(fast, np.ones(5, bool), jump=0.05)[1:].all()


def test_smoothing_and_filling_stay_inside_shots():
    """A step at a cut: smoothed across it, Savitzky-Golay (5, 2) moves the frame before it 9/35 of the
    step; by shots, both sides keep their values; a lost frame is filled from its own shot."""
    x = np.r_[np.zeros(8), np.ones(8)]
    shots = np.r_[np.zeros(8, int), np.ones(8, int)]
    assert smooth_series(x, 5, 2)[7] == pytest.approx(9 / 35)
    np.testing.assert_allclose(smooth_series(x, 5, 2, segments=shots), x, atol=1e-12)
    y = x.copy()
    y[[7, 8]] = np.nan
    found = np.isfinite(y)
    assert fill_lost(y, found)[7] == pytest.approx(1 / 3)
    np.testing.assert_allclose(fill_lost(y, found, segments=shots), x)
    # a shot without any found frame is filled from the whole series
    z = np.r_[np.nan, np.nan, 2.0, 4.0]
    np.testing.assert_allclose(fill_lost(z, np.isfinite(z), segments=[0, 0, 1, 1]), [2, 2, 2, 4])


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
    # the tracked frames' thin lines in the face frame: a bare face, no glasses to keep in front
    assert tr.rims.shape == (2, 96, 160) and np.isfinite(tr.rims).all()
    assert not rims_present(tr.rims)


def test_tracking_without_frontal_images_keeps_the_landmarks(tracked):
    tr = tracked[0]
    lean = track_driver(tr.path, frontal_images=False)
    assert lean.frontal.shape == (0, 240, 192, 3) and len(tr.frontal) > 0
    np.testing.assert_array_equal(lean.found, tr.found)
    np.testing.assert_array_equal(lean.points68, tr.points68)
    np.testing.assert_array_equal(lean.frontal_points68, tr.frontal_points68)


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


# ----------------------------------------------------------------------------- mouth correction
def _generic68(scale=100.0):
    from facetex.geometry._generic_face import load_generic_face

    p = load_generic_face().points68[:, :2]
    return p / np.linalg.norm(p[36] - p[45]) * scale + 200.0


def test_lip_fields_let_the_lips_part():
    from facetex.puppet.motion import LipFields

    p = _generic68()
    gy, gx = np.mgrid[0:400:2, 0:400:2].astype(float)
    f = LipFields(p, np.stack([gx, gy], axis=-1))
    move = np.zeros((68, 2))
    move[[61, 62, 63], 1] = -3.0  # upper lip up
    move[[65, 66, 67], 1] = +3.0  # lower lip down
    move[[50, 51, 52], 1] = -3.0
    move[[56, 57, 58], 1] = +3.0
    move[7:10, 1] = 3.0
    field = f(move)

    def at(pt):
        return field[int(round(pt[1] / 2)), int(round(pt[0] / 2))]

    gap = (p[66, 1] - p[62, 1]) / 2
    mid = (p[62] + p[66]) / 2
    assert at(mid - [0, gap * 0.8 + 1])[1] == pytest.approx(-3.0, abs=0.6)  # just above the mouth line
    assert at(mid + [0, gap * 0.8 + 1])[1] == pytest.approx(3.0, abs=0.6)  # just below it
    for still in (36, 45, 30, 19, 24):  # eyes, nose tip, brows stay where they are
        assert np.abs(at(p[still])).max() < 0.3
    # a single smooth field would have dragged both lips towards their average
    assert at(mid - [0, gap * 0.8 + 1])[1] < -2.0


def _lip_grid():
    """A 2 px grid mesh (h, w, 3) over a face with parted lips (the generic face's, tilted by 8
    degrees: its lip line slopes across the grid's rows) and the motion of lips that close past
    each other: the lower inner lip rises 2 px above the upper one."""
    from facetex.puppet.motion import LipFields

    p = _generic68()
    p[[65, 66, 67, 55, 56, 57, 58, 59]] += [0, 10.0]  # parted lips: a mouth band ~10 px tall
    a = np.deg2rad(8.0)
    p = (p - 200.0) @ np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]]) + 200.0
    gy, gx = np.mgrid[0:400:2, 0:400:2].astype(float)
    grid = np.stack([gx, gy, np.zeros_like(gx)], axis=-1)
    gap = p[[65, 66, 67], 1].mean() - p[[61, 62, 63], 1].mean()
    move = np.zeros((68, 2))
    move[[65, 66, 67, 55, 56, 57, 58, 59, 7, 8, 9], 1] = -(gap + 2.0)  # lower lip and jaw up, past the upper lip
    g = grid.copy()
    g[..., :2] += LipFields(p, grid[..., :2])(move)
    return p, grid, g


def _flipped(rest, g):
    from facetex.puppet.mesh_io import depth_to_mesh

    mask = np.ones(rest.shape[:2], bool)
    _, faces, _ = depth_to_mesh(np.zeros(rest.shape[:2]), mask)

    def det(v):
        c = v.reshape(-1, 3)[faces][:, :, :2]
        e1, e2 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
        return e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]

    return int((np.sign(det(g)) != np.sign(det(rest))).sum())


def test_unfold_columns_lets_crossing_lips_meet_without_folding_the_grid():
    from facetex.puppet.motion import unfold_columns

    p, rest, g = _lip_grid()
    mask = np.ones(rest.shape[:2], bool)
    assert _flipped(rest, g) > 20  # the old behaviour: the lower lip's rows fold over the upper lip's
    fixed = unfold_columns(g, mask)
    assert _flipped(rest, fixed) == 0
    dy = np.diff(fixed[..., 1], axis=0)
    assert dy.min() >= 0.1 * 1.99  # rows stay >= 0.1 x their spacing apart: the lips meet as a thin line
    # they meet in the middle: the upper lip is pushed up about as far as the lower lip is pushed down
    c = int(round(p[62, 0] / 2))
    moved = fixed[:, c, 1] - g[:, c, 1]
    assert moved.min() < -0.2 and moved.max() > 0.2
    # nothing changes away from the mouth, nor anywhere on an unfolded grid
    far = (np.abs(rest[..., 1] - p[62, 1]) > 40) | (np.abs(rest[..., 0] - p[62, 0]) > 80)
    np.testing.assert_array_equal(fixed[far], g[far])
    np.testing.assert_allclose(unfold_columns(rest, mask), rest)
    np.testing.assert_array_equal(fixed[..., [0, 2]], g[..., [0, 2]])


def test_closed_lips_render_as_a_smooth_line():
    """The closed lips' line, rendered: a texture whose mouth band (between the inner lips) is
    dark, closed past itself by the lip fields. Folded, the z-buffer cuts the line along the
    grid's triangles (steps of a grid cell); unfolded it is a smooth thin line."""
    from facetex.puppet.mesh_io import depth_to_mesh
    from facetex.puppet.motion import unfold_columns
    from facetex.puppet.render import render_layers

    p, rest, g = _lip_grid()
    tex = np.full((400, 400, 3), 0.8, np.float32)
    yy, xx = np.mgrid[0:400, 0:400]
    up = np.interp(xx, p[[60, 61, 62, 63, 64], 0], p[[60, 61, 62, 63, 64], 1])
    lo = np.interp(xx, p[[60, 67, 66, 65, 64], 0], p[[60, 67, 66, 65, 64], 1])
    tex[(yy >= up) & (yy <= lo)] = 0.1
    tex = cv2.GaussianBlur(tex, (0, 0), 1.0)
    mask = np.ones(rest.shape[:2], bool)
    _, faces, _ = depth_to_mesh(np.zeros(rest.shape[:2]), mask)
    uv = (rest[..., :2].reshape(-1, 2) + 0.5) / 400.0
    g = g.copy()
    g[..., 2] = -0.01 * rest[..., 1]  # lower rows nearer: a fold shows the lower sheet on top

    def line_rows(grid):  # rendered at 2x (a puppet's canonical px is ~2 output px at 720 px)
        lay = render_layers(grid.reshape(-1, 3), faces, uv, tex, rotation=2 * np.eye(3), translation=np.zeros(3),
                            size=(800, 800), supersample=1, normals=False)
        dark = np.clip(0.8 - lay.image.mean(axis=2), 0, None)
        w = p[64, 0] - p[60, 0]
        xs = np.arange(int(2 * (p[60, 0] + 0.15 * w)), int(2 * (p[64, 0] - 0.15 * w)))  # the mouth but its corners
        y0 = int(2 * p[60:68, 1].min()) - 20
        band = dark[y0: int(2 * p[60:68, 1].max()) + 20, xs]
        return (band * np.arange(len(band))[:, None]).sum(0) / np.maximum(band.sum(0), 1e-6), band.max(0)

    def steps(rows):  # the line's largest deviation from itself smoothed over ~2 grid cells
        k = np.ones(9) / 9
        return np.abs(rows - np.convolve(np.pad(rows, 4, mode="edge"), k, mode="valid")).max()

    rows_folded, strength_folded = line_rows(g)
    rows, strength = line_rows(unfold_columns(g, mask))
    # the old behaviour: the lower lip's sheet cuts the line along the grid's triangles (broken,
    # from nearly gone to full strength within a few pixels)
    assert strength_folded.min() < 0.1 and strength_folded.max() > 0.4
    # unfolded: one even, unbroken line, with no steps off its smooth course
    assert strength.min() > 0.4 and np.ptp(strength) < 0.25
    assert steps(rows) < 0.5


def test_unfold_columns_ignores_invalid_vertices():
    from facetex.puppet.motion import unfold_columns

    _, rest, g = _lip_grid()
    mask = np.ones(rest.shape[:2], bool)
    mask[:, :60] = False
    g2 = g.copy()
    g2[~mask] = np.nan
    out = unfold_columns(g2, mask)
    assert np.isnan(out[~mask]).all()
    np.testing.assert_allclose(out[mask], unfold_columns(g, np.ones_like(mask))[mask], atol=1e-3)


def test_mouth_correction_follows_the_landmarks(tracked):
    tr, n_morph, _ = tracked
    plain = driver_motion(tr)  # the default: the puppet side follows the landmarks (Puppeteer.grid)
    fixed = driver_motion(tr, DriverParams(mouth_correction=True))
    i = n_morph - 1
    st = fixed.grid_step
    f68 = fixed.fiducials68
    mean = f68[fixed.found].mean(axis=0)

    def gap_motion(m):
        d = m.delta_field(i)
        up = d[int(round(mean[62, 1] / st)) - 1, int(round(mean[62, 0] / st))]
        lo = d[int(round(mean[66, 1] / st)) + 1, int(round(mean[66, 0] / st))]
        return lo[1] - up[1]

    want = (f68[i, 66, 1] - mean[66, 1]) - (f68[i, 62, 1] - mean[62, 1])  # the landmarks' own opening
    assert abs(gap_motion(fixed) - want) < 0.35 * abs(want) + 0.5
    assert abs(gap_motion(fixed) - want) < abs(gap_motion(plain) - want)


# ----------------------------------------------------------------------------- lost-face checks
def _mesh_at(points68):
    """A stand-in face mesh: 468 points spread over the landmarks' hull, with the MediaPipe corner
    vertices on dlib's corners."""
    from facetex.puppet.driver import _DLIB_CORNERS, _MESH_CORNERS

    rng = np.random.default_rng(0)
    w = rng.dirichlet(np.ones(68), size=468)
    m = np.c_[w @ points68, np.zeros(468)]
    m[list(_MESH_CORNERS), :2] = points68[list(_DLIB_CORNERS)]
    return m


def test_face_rejection_of_partial_and_inconsistent_faces():
    from facetex.puppet.driver import face_rejection

    p = _generic68(60.0)  # face around x, y = 200 in a 400 x 400 frame
    assert face_rejection(p, _mesh_at(p), (400, 400)) == ""
    shifted = p - [p[:, 0].mean(), 0]  # the face centre on the left border: half out
    assert face_rejection(shifted, _mesh_at(shifted), (400, 400)) == "partly outside the frame"
    assert face_rejection(p, _mesh_at(p), (230, 400)) == "partly outside the frame"
    m = _mesh_at(p)
    m[:, 0] += 0.25 * 60.0  # the mesh a quarter eye distance away from the landmarks
    assert face_rejection(p, m, (400, 400)) == "landmarks disagree"


def test_implausible_shapes_flags_a_squashed_face():
    from facetex.puppet.driver import implausible_shapes

    rng = np.random.default_rng(1)
    p = _generic68(60.0)
    frames = np.array([p + rng.normal(scale=0.6, size=p.shape) for _ in range(12)])
    frames[5, :, 1] = p[:, 1].mean() + 0.6 * (p[:, 1] - p[:, 1].mean())  # squashed vertically
    found = np.ones(12, bool)
    found[9] = False
    bad = implausible_shapes(frames, found)
    assert bad.tolist() == [i == 5 for i in range(12)]


def test_track_rejects_a_face_slid_half_out_of_the_frame(tmp_path):
    """A face sliding out of the frame sideways: whole ones kept; once a fifth of it is outside,
    lost. Without the checks the trackers return squashed landmarks inside the frame there."""
    import cv2

    from facetex._resources import sample_path
    from facetex.io import read_image

    img = cv2.resize(read_image(sample_path("frl_004_neutral.jpg")), (240, 240), interpolation=cv2.INTER_AREA)
    shifts = [0, 0, 0, -20, -40, -60, -80, -100, -120]
    frames = [cv2.warpAffine(img, np.float32([[1, 0, dx], [0, 1, 0]]), (240, 240), borderMode=cv2.BORDER_REPLICATE)
              for dx in shifts]
    path = tmp_path / "sliding.mp4"
    write_video(path, frames, fps=10)
    tr = track_driver(path)
    assert tr.found[:3].all()
    width = np.ptp(tr.points68[0, :, 0])
    left = tr.points68[0, :, 0].min()
    for i, dx in enumerate(shifts):
        if left + dx < -0.2 * width:  # a fifth of the face outside
            assert not tr.found[i], i
        if tr.found[i]:  # never a squashed face
            assert abs(np.ptp(tr.points68[i, :, 0]) - width) < 0.12 * width, i
    assert "partly outside the frame" in tr.lost_causes
    assert sum(tr.lost_causes.values()) == tr.n_lost


def _lift_all(points, mesh, triangles):
    """_lift_points by trying every triangle (the definition)."""
    a, b, c = (mesh[triangles[:, k]] for k in range(3))
    e1, e2 = b[:, :2] - a[:, :2], c[:, :2] - a[:, :2]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    det = np.where(np.abs(det) < 1e-12, 1e-12, det)
    d = points[:, None, :] - a[None, :, :2]
    l1 = (d[..., 0] * e2[:, 1] - d[..., 1] * e2[:, 0]) / det
    l2 = (e1[:, 0] * d[..., 1] - e1[:, 1] * d[..., 0]) / det
    l0 = 1.0 - l1 - l2
    best = np.minimum(np.minimum(l0, l1), l2).argmax(axis=1)
    r = np.arange(len(points))
    w = np.clip(np.stack([l0[r, best], l1[r, best], l2[r, best]], axis=1), 0, None)
    w /= w.sum(axis=1, keepdims=True)
    out = np.einsum("pk,pkc->pc", w, mesh[triangles[best]])
    out[:, :2] = points
    return out


def test_lift_points_equals_search_over_all_triangles():
    from scipy.spatial import Delaunay

    from facetex.puppet.motion import _lift_points

    rng = np.random.default_rng(3)
    base = rng.uniform(0, 100, (120, 2))
    triangles = Delaunay(base).simplices
    for trial in range(5):
        mesh = np.c_[base + rng.normal(0, 2.0 * trial, base.shape), rng.normal(0, 10, len(base))]  # folds too
        pts = np.r_[rng.uniform(-20, 120, (200, 2)), mesh[:5, :2],  # outside the mesh and on vertices
                    (mesh[triangles[:3, 0], :2] + mesh[triangles[:3, 1], :2]) / 2]  # on edges (ties)
        assert np.array_equal(_lift_points(pts, mesh, triangles), _lift_all(pts, mesh, triangles))


# ----------------------------------------------------------------------------- brows
def test_brow_heights_hand_computed():
    from facetex.puppet.motion import brow_heights

    p = np.zeros((68, 2))
    p[36:42] = [10.0, 50.0]  # eye centres 40 px apart on a level line y = 50
    p[42:48] = [50.0, 50.0]
    p[17:27] = [[30.0, 50.0 - 4.0 * k] for k in range(10)]  # k x 4 px above it
    np.testing.assert_allclose(brow_heights(p), 0.1 * np.arange(10), atol=1e-12)
    # rotated and scaled: the same heights
    a = np.deg2rad(20.0)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    np.testing.assert_allclose(brow_heights(2.5 * p @ R.T + [3.0, -7.0]), 0.1 * np.arange(10), atol=1e-12)


def test_brow_fields_move_the_brows_and_hold_eyes_lips_and_hairline():
    from facetex.puppet.motion import BrowFields

    p = _generic68()
    gy, gx = np.mgrid[0:400:2, 0:400:2].astype(float)
    f = BrowFields(p, np.stack([gx, gy], axis=-1))
    move = np.zeros((68, 2))
    move[17:22, 1] = -4.0  # right brow up
    move[22:27, 1] = np.linspace(-1.0, 3.0, 5)  # left brow tilted down towards its outer end
    move[36:68] = 50.0  # not brow points: ignored
    field = f(move)

    def at(pt):
        return field[int(round(pt[1] / 2)), int(round(pt[0] / 2))]

    for k in range(17, 27):
        np.testing.assert_allclose(at(p[k]), move[k] * [0, 1], atol=0.35)
    for still in (36, 39, 42, 45, 37, 44, 30, 33, 48, 54, 62, 66, 8):
        assert np.abs(at(p[still])).max() < 0.3
    iod = np.linalg.norm(p[36:42].mean(axis=0) - p[42:48].mean(axis=0))
    assert np.abs(at(p[19] - [0, 0.6 * iod])).max() < 0.3  # the forehead fades back to still
    assert at(p[19] - [0, 0.2 * iod])[1] < -1.0  # skin just above the brow goes with it


def test_eye_openness_hand_computed():
    from facetex.puppet.motion import eye_openness

    p = np.zeros((68, 2))
    for c0, u0, u1, c1, l1, l0 in ((36, 37, 38, 39, 40, 41), (42, 43, 44, 45, 46, 47)):
        p[[c0, c1]] = [[0, 0], [10, 0]]  # eye 10 px wide
        p[[u0, u1]] = [[3, -1], [7, -2]]
        p[[l0, l1]] = [[3, 2], [7, 2]]  # lid gaps 3 and 4 px
    assert eye_openness(p) == pytest.approx((3 + 4) / (2 * 10))
    p[[43, 44], 1] = 2.0  # right eye shut: its ratio 0
    assert eye_openness(p) == pytest.approx(0.35 / 2)
    assert eye_openness(np.stack([p, p])).shape == (2,)


def test_lid_fields_close_the_lids_and_hold_the_rest():
    from facetex.puppet.motion import LidFields

    p = _generic68()
    gy, gx = np.mgrid[0:400:2, 0:400:2].astype(float)
    f = LidFields(p, np.stack([gx, gy], axis=-1))
    move = np.zeros((68, 2))
    move[[37, 38, 43, 44], 1] = +3.0  # upper lids down (a blink)
    move[[41, 40, 47, 46], 1] = -1.0  # lower lids up a little
    move[[48, 54, 8], 1] = 50.0  # not lid points: ignored
    field = f(move)

    def at(pt):
        return field[int(round(pt[1] / 2)), int(round(pt[0] / 2))]

    for up, lo in ((37, 41), (38, 40), (43, 47), (44, 46)):
        gap = p[lo, 1] - p[up, 1]
        assert at(p[up] - [0, 0.2 * gap])[1] == pytest.approx(3.0, abs=0.8)  # just above the upper lid
        assert at(p[lo] + [0, 0.2 * gap])[1] == pytest.approx(-1.0, abs=0.5)  # just below the lower lid
    for still in (36, 39, 42, 45, 19, 24, 30, 48, 57, 8):  # eye corners, brows, nose, mouth, chin
        assert np.abs(at(p[still])).max() < 0.3


def test_a_carried_box_refits_a_dark_mouth_once(monkeypatch):
    """Between detections the landmarks are fitted 1 + landmark_refits times; on a dark face only
    the last fit refits the mouth at a normalised exposure (the earlier fits only place its box), and
    exposure=False gives the plain fit."""
    import facetex._landmark_fit as fit
    import facetex.puppet.driver as drv
    from facetex._resources import sample_path
    from facetex.io import read_image
    from facetex.landmarks import detect_faces

    img = read_image(sample_path("frl_004_smiling.jpg"))
    dark = img * np.float32(0.25)
    face = detect_faces(img)[0]
    calls = []
    real = fit._mouth_exposed
    monkeypatch.setattr(fit, "_mouth_exposed", lambda *a: calls.append(1) or real(*a))
    plain = fit.fit_landmarks(dark, face.box, exposure=False)
    assert not calls
    assert np.abs(fit.fit_landmarks(dark, face.box) - plain)[48:].max() > 0  # the refit moves the mouth
    assert len(calls) == 1
    for refits in (0, 1, 2):
        calls.clear()
        params = drv.DriverParams(landmark_refits=refits, landmark_mirror=False)
        out = drv._track_frame(dark, (face.points68, (face.box, face.points68)), params, detect=False)
        assert out is not None and len(calls) == 1, refits
        calls.clear()  # with the mirror fit averaged in: its mouth too, once
        params = drv.DriverParams(landmark_refits=refits, landmark_mirror=True)
        assert drv._track_frame(dark, (face.points68, (face.box, face.points68)), params, detect=False) is not None
        assert len(calls) == 2, refits


def test_the_tracker_averages_only_the_last_fit_with_its_mirror_when_asked(monkeypatch):
    """landmark_mirror: between detections only the last of the 1 + landmark_refits fits is averaged
    with the mirror image's fit (the earlier ones place its box), and a detection's fit is too; off,
    none is."""
    import facetex._landmark_fit as fit
    import facetex.puppet.driver as drv
    from facetex._resources import sample_path
    from facetex.io import read_image
    from facetex.landmarks import detect_faces

    img = read_image(sample_path("frl_004_smiling.jpg"))
    face = detect_faces(img)[0]
    calls = []
    real = fit.mirror_averaged
    monkeypatch.setattr(fit, "mirror_averaged", lambda *a, **k: calls.append(1) or real(*a, **k))
    for mirror, detect, refits, n in ((True, False, 0, 1), (True, False, 2, 1), (True, True, 1, 1),
                                      (False, False, 1, 0), (False, True, 1, 0)):
        calls.clear()
        params = drv.DriverParams(landmark_refits=refits, landmark_mirror=mirror)
        out = drv._track_frame(img, (face.points68, (face.box, face.points68)), params, detect=detect)
        assert out is not None and len(calls) == n, (mirror, detect, refits)


def test_motion_of_an_edited_clip_is_not_smoothed_across_its_cut(tmp_path):
    """A neutral portrait for 6 frames, then the same person smiling, moved: two shots; the pose of
    the frame before the cut is its own shot's (smoothed across, it took 9/35 of the jump)."""
    from facetex.io import read_image
    from facetex.puppet import driver as drv

    samples = drv.Path(__file__).resolve().parents[2] / "facetex" / "data" / "samples"
    a, b = (read_image(samples / f"frl_004_{k}.jpg") for k in ("neutral", "smiling"))
    b = np.roll(b, 60, axis=1)  # the second shot framed 60 px further right
    clip = tmp_path / "cut.mp4"
    write_video(clip, [a] * 6 + [b] * 6, 25.0)
    motion = driver_motion(track_driver(clip, frontal_images=False))
    # the first frame after the cut may be lost (the carried landmarks disagree) and held from shot 0
    assert (motion.shots[:6] == 0).all() and (motion.shots[7:] == 1).all()
    np.testing.assert_allclose(motion.pose_b[5], motion.pose_b[3], atol=1.0)
    assert motion.pose_b[7, 0] - motion.pose_b[5, 0] > 50
