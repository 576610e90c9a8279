"""Deformation transfer with magnitude adjustment and Huber-ROF (Tom Hanks §4, Fig. 3)."""

import numpy as np
import pytest
from skimage.restoration import denoise_tv_chambolle

from facetex.errors import BadInputError
from facetex.puppet.deform import DeformationTransfer, DeformParams, huber_rof, invert_map, transfer_deformation

H, W = 60, 50


def _grid(h=H, w=W):
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    return xx, yy


def test_huber_rof_removes_noise_and_keeps_the_step():
    rng = np.random.default_rng(0)
    clean = np.zeros((40, 60), np.float32)
    clean[:, 30:] = 1.0
    noisy = clean + rng.normal(scale=0.1, size=clean.shape).astype(np.float32)
    u = huber_rof(noisy, weight=0.2, epsilon=0.05, iters=200)
    assert np.sqrt(((u - clean) ** 2).mean()) < 0.5 * np.sqrt(((noisy - clean) ** 2).mean())
    assert u[:, 33:].mean() - u[:, :27].mean() > 0.9  # the edge survives (not blurred away)
    assert np.abs(huber_rof(noisy, weight=1e-6) - noisy).max() < 1e-4
    np.testing.assert_array_equal(huber_rof(noisy, weight=0.0), noisy)


def test_huber_rof_matches_tv_rof_when_epsilon_is_zero():
    g = np.random.default_rng(1).normal(size=(30, 40)).astype(np.float32)
    ours = huber_rof(g, weight=0.3, epsilon=0.0, iters=2000)
    ref = denoise_tv_chambolle(g, weight=0.3, eps=1e-9, max_num_iter=5000)
    assert np.abs(ours - ref).max() < 0.02


def test_huber_rof_mask_isolates_pixels():
    f = np.zeros((20, 20), np.float32)
    f[5:15, 5:15] = 1.0
    mask = np.zeros((20, 20), bool)
    mask[5:15, 5:15] = True
    u = huber_rof(f, weight=1.0, mask=mask)
    np.testing.assert_allclose(u[mask], 1.0, atol=1e-5)  # constant inside: no leak from outside
    np.testing.assert_array_equal(u[~mask], 0.0)


def _surface_following(depth, dx, dy):
    """Δ that moves along z = depth (x, y) by (dx, dy)."""
    from scipy.ndimage import map_coordinates

    xx, yy = _grid(*depth.shape)
    z1 = map_coordinates(depth, [yy + dy, xx + dx], order=1, mode="nearest")
    return np.stack([dx, dy, z1 - depth], axis=-1)


def test_identity_transfer_reproduces_the_driver():
    xx, yy = _grid()
    depth = 0.02 * (xx - 25) ** 2 + 0.01 * (yy - 30) ** 2
    mesh = np.stack([xx, yy, depth], axis=-1)
    bump = np.exp(-((xx - 25) ** 2 + (yy - 30) ** 2) / (2 * 10.0**2))
    delta = _surface_following(depth, 2.0 * bump, 3.0 * bump)
    corr = np.stack([xx, yy], axis=-1)
    out = transfer_deformation(mesh, delta, mesh, corr, inverse=corr)
    err = np.linalg.norm(out - (mesh + delta), axis=-1)
    moving = np.linalg.norm(delta, axis=-1) > 1.0
    assert np.median(err[moving] / np.linalg.norm(delta, axis=-1)[moving]) < 0.05
    assert err.mean() < 0.1
    # the paper's nearest vertex only: close, but quantised to the grid
    coarse = transfer_deformation(mesh, delta, mesh, corr, inverse=corr, params=DeformParams(subvertex=False))
    assert np.linalg.norm(coarse - (mesh + delta), axis=-1).mean() < 0.4


def test_bigger_puppet_feature_gets_bigger_deformation():
    xx, yy = _grid()
    driver = np.stack([xx, yy, np.zeros_like(xx)], axis=-1)
    w2 = int(1.5 * (W - 1)) + 1
    px, py = _grid(H, w2)
    puppet = np.stack([px, py, np.zeros_like(px)], axis=-1)  # the driver stretched 1.5x in x
    corr = np.stack([xx * 1.5, yy], axis=-1)
    bump = np.exp(-((xx - 25) ** 2 + (yy - 30) ** 2) / (2 * 10.0**2))
    delta = np.stack([3.0 * bump, np.zeros_like(xx), np.zeros_like(xx)], axis=-1)
    dt = DeformationTransfer(driver, puppet, corr)  # inverse map computed by invert_map
    moved = dt(delta) - puppet
    sel = bump > 0.5
    at = np.rint(corr[sel]).astype(int)
    ratio = moved[at[:, 1], at[:, 0], 0] / delta[sel][:, 0]
    assert 1.35 < np.median(ratio) < 1.6
    assert np.abs(moved[..., 1:]).max() < 1e-6
    # the same deformation on an unstretched copy stays ~1x
    same = transfer_deformation(driver, delta, driver, np.stack([xx, yy], -1)) - driver
    assert 0.9 < np.median(same[sel][:, 0] / delta[sel][:, 0]) < 1.1


def test_invert_map_of_a_scaling():
    xx, yy = _grid()
    inv = invert_map(np.stack([xx * 1.5, yy], -1), np.ones((H, W), bool), (H, 74))
    px, py = _grid(H, 74)
    # cv2.remap samples at 1/32 px
    np.testing.assert_allclose(inv[..., 0], px / 1.5, atol=0.02)
    np.testing.assert_allclose(inv[..., 1], py, atol=0.02)
    # a non-affine map: F(B(y)) = y
    fwd = np.stack([xx + 2 * np.sin(yy / 10), yy + 0.01 * xx**1.5], -1)
    inv = invert_map(fwd, np.ones((H, W), bool), (H, W))
    from scipy.ndimage import map_coordinates

    back = [map_coordinates(fwd[..., k], [inv[..., 1], inv[..., 0]], order=1) for k in range(2)]
    inner = (slice(5, -5), slice(5, -5))
    np.testing.assert_allclose(back[0][inner], xx[inner], atol=0.05)
    np.testing.assert_allclose(back[1][inner], yy[inner], atol=0.05)


def test_invert_map_of_a_folded_map_is_continuous():
    """A map that folds over (a torn correspondence) has no inverse: the result must still be a
    continuous source position near the fold (it used to end on the grid's corner: puppet
    vertices that never move), and exact where the map is smooth."""
    xx, yy = _grid()
    fwd = np.stack([xx.copy(), yy.copy()], -1)
    band = (xx >= 20) & (xx < 26)
    fwd[..., 0] = np.where(band, 20 + 2.0 * (25 - xx), xx)  # columns 20..25 run backwards: a fold
    inv = invert_map(fwd, np.ones((H, W), bool), (H, W))
    assert np.isfinite(inv).all()
    assert inv[..., 0].min() >= 0 and inv[..., 0].max() <= W - 1
    # no jumps: neighbouring targets have nearby sources (the fold spans 6 columns)
    assert np.abs(np.diff(inv[..., 0], axis=1)).max() < 6.0
    assert np.abs(np.diff(inv[..., 1], axis=0)).max() < 1.5
    # rows are never mixed up (the first and last one a little pulled inwards by the splat where
    # the map folds), and far from the fold the inverse is the identity
    np.testing.assert_allclose(inv[1:-1, :, 1], yy[1:-1], atol=0.2)
    far = (xx < 12) | (xx > 36)
    np.testing.assert_allclose(inv[..., 0][far], xx[far], atol=0.05)


def test_invert_map_outside_the_forward_image_takes_the_nearest_source():
    xx, yy = _grid()
    fwd = np.stack([xx + 10.0, yy], -1)  # the source covers target columns 10..59 of 70
    inv = invert_map(fwd, np.ones((H, W), bool), (H, 70))
    assert np.abs(inv[:, :8, 0]).max() < 0.6  # left of the image: the first source column
    np.testing.assert_allclose(inv[:, 12:58, 0], xx[:, 2:48], atol=0.05)


def test_puppet_beyond_the_drivers_mask_moves_with_the_nearest_driver_vertex():
    xx, yy = _grid()
    mesh = np.stack([xx, yy, np.zeros_like(xx)], -1)
    dmask = (xx >= 10) & (xx < 40) & (yy >= 10) & (yy < 50)
    delta = np.zeros_like(mesh)
    delta[..., 1] = 2.0  # everything moves down by 2 px
    corr = np.stack([xx, yy], -1)
    out = DeformationTransfer(mesh, mesh, corr, driver_mask=dmask, inverse=corr)(delta) - mesh
    assert np.allclose(out[..., 1], 2.0, atol=0.05)  # also the puppet's vertices off the driver's mask


def test_rejects_mismatched_shapes():
    xx, yy = _grid()
    mesh = np.stack([xx, yy, 0 * xx], -1)
    corr = np.stack([xx, yy], -1)
    with pytest.raises(BadInputError):
        DeformationTransfer(mesh, mesh, corr[:-1])
    dt = DeformationTransfer(mesh, mesh, corr, inverse=corr)
    with pytest.raises(BadInputError):
        dt(np.zeros((H, W, 2)))
