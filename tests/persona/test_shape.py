"""Average shape (Tom Hanks §4 / KS&S 2011) and depth-map meshes."""

import numpy as np
import pytest
from scipy import ndimage

from facetex.errors import BadInputError
from facetex.geometry._generic_face import canonical_surface
from facetex.persona.mesh_io import depth_to_mesh, read_obj, write_obj
from facetex.persona.shape import (
    checked_depth,
    generic_depth_px,
    integrate_normals,
    normals_from_depth,
    reconstruct_average_shape,
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
    images = np.stack(images) + rng.normal(scale=noise, size=(n, H, W))
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
    # the raw SVD factor read as [ρ, ρn] (no ambiguity resolution) is far worse
    raw = reconstruct_average_shape(images, face_mask, resolve_ambiguity=False)
    assert _corr(raw.depth, truth, face_mask) < c_with - 0.5
    # normals point to the camera and match the truth's
    cos = (shape.normals[face_mask] * normals_from_depth(truth)[face_mask]).sum(-1)
    assert np.median(cos) > 0.95
    # the albedo pattern is recovered up to scale
    alb = 0.5 + 0.2 * np.sin(xx / 9.0) * np.cos(yy / 13.0)
    assert _corr(shape.albedo, alb, face_mask) > 0.9


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
