"""Occluders in a persona's photos (facetex.persona._occlusion) on hand-made band maps (a hand painted
over one photo of a built collection: tests/persona/test_collection.py)."""

import numpy as np
import pytest

from facetex.persona._occlusion import FLOOR, band_structure, judged_region, occlusion_factors

H, W = 60, 48  # a quarter of the canonical frame: blur 0.75 px, growth 2 px


def _collection(n=12, seed=0):
    """n photos' bands: one shared structure (a face's) plus each photo's own faint noise."""
    rng = np.random.default_rng(seed)
    shared = rng.normal(0, 1, (H, W)).astype(np.float32)
    bands = np.stack([shared + rng.normal(0, 0.2, (H, W)).astype(np.float32) for _ in range(n)])
    coords = rng.normal(0, 1, (n, 6))
    return bands, np.ones((n, H, W), bool), coords


def _stripes(shape=(16, 16)):
    return np.where((np.arange(shape[1]) // 2) % 2 == 0, 4.0, -4.0).astype(np.float32)[None].repeat(shape[0], 0)


PATCH = (slice(20, 36), slice(16, 32))


def test_a_patch_on_one_photo_is_judged_an_occluder_there_only():
    bands, sure, coords = _collection()
    bands[5][PATCH] += _stripes()
    f = occlusion_factors(bands, sure, coords, np.ones((H, W), np.float32), kappa=2.5)
    assert f.shape == (12, H, W) and f.dtype == np.float32
    assert f[5][28, 24] < 0.2  # the patch's middle
    assert f[5][:8].min() > 0.9 and f[5][52:].min() > 0.9  # far from it
    others = np.delete(f, 5, axis=0)
    assert others.mean() > 0.97
    assert f.min() >= FLOOR - 1e-6 and f.max() <= 1.0


def test_nothing_is_judged_outside_the_judged_region_or_with_kappa_zero():
    bands, sure, coords = _collection()
    bands[5][PATCH] += _stripes()
    judged = np.ones((H, W), np.float32)
    judged[PATCH] = 0.0
    f = occlusion_factors(bands, sure, coords, judged, kappa=2.5)
    assert f[5][28, 24] == pytest.approx(1.0)  # the patch lies where nothing is judged
    assert (occlusion_factors(bands, sure, coords, np.ones((H, W)), kappa=0) == 1).all()
    assert (occlusion_factors(bands[:2], sure[:2], coords[:2], np.ones((H, W)), kappa=2.5) == 1).all()


def test_structure_shared_with_the_nearest_expressions_is_not_an_occluder():
    """Four photos with the same expression share a crease pattern; a fifth, far from them in
    expression, has it alone: it is judged an occluder, the four are not."""
    bands, sure, coords = _collection(n=16)
    group = [0, 1, 2, 3]
    coords[group] = coords[0] + np.random.default_rng(1).normal(0, 0.01, (4, coords.shape[1]))
    for i in group + [9]:
        bands[i][PATCH] += _stripes()
    f = occlusion_factors(bands, sure, coords, np.ones((H, W), np.float32), kappa=2.5, neighbours=3)
    assert min(f[i][28, 24] for i in group) > 0.9
    assert f[9][28, 24] < 0.2


def test_band_structure_ignores_flat_and_linear_light():
    ramp = np.linspace(0.2, 0.8, 192, dtype=np.float32)[None, :, None].repeat(240, 0).repeat(3, 2)
    assert np.abs(band_structure(ramp)[40:-40, 40:-40]).max() < 1e-4
    assert np.abs(band_structure(np.full((240, 192, 3), 0.5, np.float32))).max() < 1e-6
    img = np.full((240, 192, 3), 0.5, np.float32)
    img[100:140, 80:84] = 0.9  # a light strand
    assert band_structure(img)[120, 82] > 0.1


def test_the_judged_region_leaves_out_the_lips_eyes_and_brows():
    from facetex.geometry.frontalize import canonical_points68
    from facetex.geometry.masks import face_mask

    p = canonical_points68()
    j = judged_region(p, (240, 192), face_mask(p, (240, 192)))
    mouth, eye = np.round(p[62]).astype(int), np.round(p[37:39].mean(0)).astype(int)
    cheek = np.round((p[3] + p[31]) / 2).astype(int)
    assert j[mouth[1], mouth[0]] < 0.05 and j[eye[1], eye[0]] < 0.05
    assert j[cheek[1], cheek[0]] > 0.9
    assert j[5, 5] < 0.05  # off the face


def test_the_papers_settings_make_their_stacks_from_the_photos_as_they_are():
    from facetex.persona import TextureParams
    from facetex.puppet import PuppetParams

    assert TextureParams().occlusion == 2.5
    assert TextureParams.paper().occlusion == 0.0
    assert PuppetParams(weights="global").texture_params().occlusion == 0.0
    assert PuppetParams().texture_params().occlusion == 2.5
    # without the factors the stack key is the one files stored before them
    assert not any(isinstance(k, tuple) and k[0] == "occlusion" for k in TextureParams.paper().stack_key())
