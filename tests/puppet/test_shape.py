"""Average shape (Tom Hanks §4 / KS&S 2011) and depth-map meshes."""

import numpy as np
import pytest
from scipy import ndimage

from facetex.errors import BadInputError
from facetex.geometry._generic_face import canonical_surface
from facetex.puppet.mesh_io import depth_to_mesh, read_obj, write_obj
from facetex.puppet.shape import (
    checked_depth,
    fit_albedo,
    generic_depth_px,
    integrate_normals,
    linear_luma,
    normals_from_depth,
    reconstruct_average_shape,
    symmetrize_normals,
    validate_shape,
)

W, H = 192, 240


@pytest.fixture(scope="module")
def face_mask():
    return ndimage.binary_erosion(canonical_surface((W, H)).on_mesh, iterations=3)


def _collection(depth, n=12, seed=0, noise=0.003):
    """Lambertian first-order SH renderings I = ρ (l0 + l · n) under random directional lights."""
    rng = np.random.default_rng(seed)
    normals = normals_from_depth(depth)
    yy, xx = np.mgrid[0:H, 0:W]
    albedo = 0.5 + 0.2 * np.sin(xx / 9.0) * np.cos(yy / 13.0)
    images = []
    for _ in range(n):
        d = rng.normal(size=3)
        d[2] = -abs(d[2]) - 0.8  # towards the camera (normals have n_z < 0)
        d /= np.linalg.norm(d)
        images.append(albedo * (rng.uniform(0.3, 0.7) + normals @ (0.6 * d)))
    images = np.clip(np.stack(images) + rng.normal(scale=noise, size=(n, H, W)), 0, 1)
    # photos are sRGB-encoded: the reconstruction decodes them back to linear light
    images = np.where(images <= 0.0031308, 12.92 * images, 1.055 * images ** (1 / 2.4) - 0.055)
    return np.repeat(images[..., None], 3, axis=-1).astype(np.float32)


def _corr(a, b, mask):
    return np.corrcoef(a[mask], b[mask])[0, 1]


def test_reconstructs_a_face_unlike_the_template(face_mask):
    yy, xx = np.mgrid[0:H, 0:W]
    # deeper than the generic face and with a cheek bump: the template only fixes the ambiguity
    truth = 1.3 * generic_depth_px((W, H)) + 8.0 * np.exp(-((xx - 70) ** 2 + (yy - 150) ** 2) / 200.0)
    images = _collection(truth)
    shape = reconstruct_average_shape(images, face_mask)
    assert shape.depth.shape == (H, W) and shape.lighting.shape == (12, 4)
    assert np.isnan(shape.depth[~face_mask]).all()
    c_with = _corr(shape.depth, truth, face_mask)
    assert c_with > 0.9
    # the raw factor read as [ρ, ρn] (no ambiguity resolution) gives far worse normals
    raw = reconstruct_average_shape(images, face_mask, resolve_ambiguity=False)
    cos_raw = (raw.normals[face_mask] * normals_from_depth(truth)[face_mask]).sum(-1)
    assert np.median(cos_raw) < 0.85
    # normals point to the camera and match the truth's
    cos = (shape.normals[face_mask] * normals_from_depth(truth)[face_mask]).sum(-1)
    assert np.median(cos) > 0.95
    # the albedo (refitted to the final, integrated shape) follows the pattern; its error is the
    # normals' (a few degrees): with the template's relief scale (a bas-relief parameter the template
    # fixes; a deeper face gets a distorted albedo) the correlation stays high
    alb = 0.5 + 0.2 * np.sin(xx / 9.0) * np.cos(yy / 13.0)
    flat_scale = generic_depth_px((W, H)) + 8.0 * np.exp(-((xx - 70) ** 2 + (yy - 150) ** 2) / 200.0)
    assert _corr(reconstruct_average_shape(_collection(flat_scale), face_mask).albedo, alb, face_mask) > 0.78
    # with the true normals, the albedo fit itself is accurate
    Y = linear_luma(_collection(flat_scale))[:, face_mask]
    rho, light = fit_albedo(Y, np.ones_like(Y), normals_from_depth(flat_scale)[face_mask])
    got = np.zeros((H, W))
    got[face_mask] = rho
    assert _corr(got, alb, face_mask) > 0.93 and light.shape == (12, 4)


def test_integrate_normals_recovers_a_sphere_cap():
    yy, xx = np.mgrid[0:60, 0:50].astype(float)
    r2 = (xx - 25) ** 2 + (yy - 30) ** 2
    mask = r2 < 20**2
    z = -np.sqrt(40.0**2 - r2)
    got = integrate_normals(normals_from_depth(z), mask)
    err = (got - got[mask].mean()) - (z - z[mask].mean())
    assert np.abs(err[mask]).max() < 0.2  # pixels, on a cap 5 px deep


def test_rejects_bad_input(face_mask):
    with pytest.raises(BadInputError):
        reconstruct_average_shape(np.zeros((3, H, W, 3), np.float32), face_mask)  # fewer photos than rank
    with pytest.raises(BadInputError):
        reconstruct_average_shape(np.zeros((8, 10, 10, 3), np.float32), face_mask)


def test_depth_to_mesh_counts_and_winding():
    depth = np.arange(12, dtype=float).reshape(3, 4)
    mask = np.ones((3, 4), bool)
    v, f, uv = depth_to_mesh(depth, mask)
    assert v.shape == (12, 3) and f.shape == (2 * 2 * 3, 3) and uv.shape == (12, 2)
    np.testing.assert_allclose(v[5], [1, 1, 5])
    np.testing.assert_allclose(uv[0], [0.5 / 4, 0.5 / 3])
    # counter-clockwise seen from the camera with y up: positive area in (x, -y)
    p = v[f][:, :, :2] * [1, -1]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    assert (area > 0).all()
    # a masked corner leaves one triangle in that cell; step subsamples
    mask[0, 0] = False
    assert len(depth_to_mesh(depth, mask)[1]) == 11
    assert len(depth_to_mesh(np.zeros((5, 5)), step=2)[1]) == 8


def test_write_obj_roundtrip(tmp_path):
    depth = generic_depth_px((W, H))
    mask = canonical_surface((W, H)).on_mesh
    v, f, uv = depth_to_mesh(depth, mask, step=4)
    tex = np.random.default_rng(0).random((H, W, 3)).astype(np.float32)
    out = write_obj(tmp_path / "face.obj", v, f, uv, tex)
    assert {p.name for p in tmp_path.iterdir()} == {"face.obj", "face.mtl", "face.png"}
    text = out.read_text()
    assert "mtllib face.mtl" in text and "map_Kd face.png" in (tmp_path / "face.mtl").read_text()
    assert sum(line.startswith("v ") for line in text.splitlines()) == len(v)
    assert sum(line.startswith("f ") for line in text.splitlines()) == len(f)
    v2, f2, uv2 = read_obj(out)
    np.testing.assert_allclose(v2, v, atol=1e-5)
    np.testing.assert_array_equal(f2, f)
    np.testing.assert_allclose(uv2, uv, atol=1e-5)
    # the y axis is flipped for viewers: first vertex line is (x, -y, -z)
    first = next(line for line in text.splitlines() if line.startswith("v "))
    np.testing.assert_allclose([float(t) for t in first.split()[1:]], v[0] * [1, -1, -1], atol=1e-5)


def test_checked_depth_accepts_plausible_and_falls_back(face_mask):
    gen = generic_depth_px((W, H))
    # a plausible depth: the template plus a 5 px bump (RMS well under 0.08 W = 15.4 px), NaN off the mask
    yy, xx = np.mgrid[0:H, 0:W]
    bump = 5.0 * np.exp(-((xx - W / 2) ** 2 + (yy - H / 2) ** 2) / (2 * 20.0**2))
    d = np.where(face_mask, gen + bump, np.nan)
    hole = d.copy()
    hole[H // 2, W // 2] = np.nan
    out, src = checked_depth(hole, face_mask, (W, H))
    assert src == "collection" and out.dtype == np.float64 and np.isfinite(out[face_mask]).all()
    assert out[H // 2, W // 2] == gen[H // 2, W // 2]  # hole filled with the template
    assert np.allclose(out[face_mask & np.isfinite(hole)], hole[face_mask & np.isfinite(hole)])
    # RMS 16 px > 15.36 px: rejected; 15 px passes (the threshold is max_error * W)
    assert checked_depth(np.where(face_mask, gen + 16.0, np.nan), face_mask, (W, H))[1] == "generic"
    assert checked_depth(np.where(face_mask, gen + 15.0, np.nan), face_mask, (W, H))[1] == "collection"
    assert checked_depth(np.where(face_mask, gen + 15.0, np.nan), face_mask, (W, H), max_error=0.05)[1] == "generic"
    # finite on at most half of the region, all NaN, or None: the generic face
    half = d.copy()
    half[:, : W // 2] = np.nan
    half[: H // 2] = np.nan
    for bad in (half, np.full((H, W), np.nan), None):
        out, src = checked_depth(bad, face_mask, (W, H))
        assert src == "generic" and np.array_equal(out, gen, equal_nan=True)
    with pytest.raises(BadInputError):
        checked_depth(np.zeros((10, 10)), face_mask, (W, H))


def _renders(depth, lights, albedo=None):
    """sRGB renders (n, H, W, 3) of a Lambertian face under the given (n, 4) first-order SH lights."""
    normals = normals_from_depth(depth)
    yy, xx = np.mgrid[0:H, 0:W]
    alb = 0.5 + 0.2 * np.sin(xx / 9.0) * np.cos(yy / 13.0) if albedo is None else albedo
    lin = np.clip(alb * (lights[:, :1, None] + np.einsum("nk,hwk->nhw", lights[:, 1:], normals)), 0, 1)
    srgb = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)
    return np.repeat(srgb[..., None], 3, axis=-1).astype(np.float32)


def _lights(n, seed):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d[:, 2] = -np.abs(d[:, 2]) - 0.8
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.c_[rng.uniform(0.3, 0.6, n), 0.6 * d]


def _cos(shape, truth, mask):
    return float(np.median((shape.normals[mask] * normals_from_depth(truth)[mask]).sum(-1)))


def test_visible_half_only(face_mask):
    # each photo saw one half of the face; the other half is the mirrored fill of the frontalization
    # (the other cheek under mirrored light): with the visibility it is ignored, without it corrupts
    truth = generic_depth_px((W, H))
    imgs = _renders(truth, _lights(16, 1))
    vis = np.ones((16, H, W), np.float32)
    half = np.arange(W) < W // 2
    for i in range(16):
        side = half if i % 2 else ~half
        vis[i][:, side] = 0
        imgs[i][:, side] = imgs[i][:, ::-1][:, side]
    good = reconstruct_average_shape(imgs, face_mask, visibility=vis)
    bad = reconstruct_average_shape(imgs, face_mask)
    assert _cos(good, truth, face_mask) > 0.97 and _cos(good, truth, face_mask) > _cos(bad, truth, face_mask) + 0.01


def test_robust_to_highlights_and_shadows(face_mask):
    truth = generic_depth_px((W, H)) + 6.0 * np.exp(-(((np.mgrid[0:H, 0:W][1] - 96) ** 2) / 300.0))
    imgs = _renders(truth, _lights(20, 2))
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:H, 0:W]
    for i in range(0, 20, 2):  # specular blobs and cast-shadow patches in half of the photos
        cy, cx = rng.integers(60, 200), rng.integers(50, 140)
        blob = ((yy - cy) ** 2 + (xx - cx) ** 2) < 12**2
        imgs[i][blob] = 0.97 if i % 4 else 0.08
    robust = reconstruct_average_shape(imgs, face_mask)
    plain = reconstruct_average_shape(imgs, face_mask, robust=False)
    err = [float(np.sqrt(np.nanmean((s.depth - truth)[face_mask] ** 2))) for s in (robust, plain)]
    assert err[0] < 0.9 * err[1], err


def test_validation_prefers_the_true_shape(face_mask):
    # a face unlike the template (deep cheeks, a long nose ridge) under known lights: its reconstruction
    # explains held-out photos' shading better than the generic face does, and is accepted
    yy, xx = np.mgrid[0:H, 0:W]
    gen = generic_depth_px((W, H))
    truth = gen + 10.0 * np.exp(-(((xx - 60) ** 2 + (yy - 140) ** 2) / 300.0)) \
        + 10.0 * np.exp(-(((xx - 132) ** 2 + (yy - 140) ** 2) / 300.0)) - 6.0 * np.exp(-((xx - 96) ** 2) / 40.0)
    train, test = _renders(truth, _lights(16, 4)), _renders(truth, _lights(6, 5))
    shape = reconstruct_average_shape(train, face_mask)
    v = validate_shape(shape.depth, train, None, test, None, face_mask)
    assert v.accepted and v.rms_person < 0.9 * v.rms_generic and v.wins > 0.8 and v.photos == 6
    d = v.as_dict()
    assert d["accepted"] is True and "better" in d["reason"] and d["relative_gain"] > 0.1
    # the true depth explains them better still
    exact = validate_shape(truth, train, None, test, None, face_mask)
    assert exact.rms_person < 0.8 * v.rms_person
    # the generic face itself does not beat the generic face: rejected
    same = validate_shape(np.where(face_mask, gen, np.nan), train, None, test, None, face_mask)
    assert not same.accepted and same.rms_person >= same.rms_generic - 1e-9
    # a depth with no finite value is rejected with a reason
    assert "no finite depth" in validate_shape(np.full((H, W), np.nan), train, None, test, None, face_mask).reason


def test_symmetrize_normals_hand_case():
    n = np.zeros((2, 4, 3))
    n[..., 2] = -1.0
    n[0, 0] = [0.6, 0.0, -0.8]  # left column tilted; its mirror (column 3) is flat
    out = symmetrize_normals(n, np.ones((2, 4), bool))
    # (0.6, 0, -0.8) + (-0, 0, -1) mirrored -> (0.6, 0, -1.8) / |.| on the left, x negated on the right
    want = np.array([0.6, 0.0, -1.8]) / np.linalg.norm([0.6, 0.0, -1.8])
    np.testing.assert_allclose(out[0, 0], want)
    np.testing.assert_allclose(out[0, 3], want * [-1, 1, 1])
    np.testing.assert_allclose(out[1, 1], [0, 0, -1])
