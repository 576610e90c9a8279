"""Putting the puppet into the driver's frame: colour/lighting transfer, blending, masks, the
boundary colour-step measure and the mouth interior, on hand-computed cases."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facetex.errors import BadInputError
from facetex.geometry.masks import inner_feather, nose_mask, polygon_mask
from facetex.puppet.composite import (
    CompositeParams,
    boundary_color_step,
    composite_face,
    match_sharpness,
    occlusion_mask,
    poisson_blend,
    skin_pixels,
)
from facetex.puppet.mouth import lip_regions, lip_weights, open_lip_weights
from facetex.puppet.lighting import (
    fit_sh_lighting,
    floor_nostrils,
    linear_to_srgb,
    match_color_statistics,
    relight,
    sh_shading,
    skin_low_pass,
    srgb_to_linear,
    transfer_skin_colour,
)
from facetex.puppet.mouth import fill_mouth_interior, lift_inner_lips, mouth_closure, mouth_interior


def _lab(img):
    return cv2.cvtColor(np.asarray(img, np.float32), cv2.COLOR_RGB2Lab)


def _disc(h=64, w=64, cx=32.0, cy=32.0, r=20.0):
    yy, xx = np.mgrid[0:h, 0:w]
    return (xx - cx) ** 2 + (yy - cy) ** 2 <= r * r


def _sphere_normals(h=64, w=64, r=30.0):
    """Unit normals of a sphere seen from the camera (z away from it: frontal normal (0, 0, -1))."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    x, y = (xx - (w - 1) / 2) / r, (yy - (h - 1) / 2) / r
    inside = x * x + y * y < 0.95
    z = -np.sqrt(np.clip(1 - x * x - y * y, 0, 1))
    n = np.stack([x, y, z], axis=-1)
    n[~inside] = 0
    return n.astype(np.float32), inside


# ----------------------------------------------------------------------------- colour statistics
@pytest.mark.parametrize("std", [False, True])
def test_colour_transfer_moves_the_lab_statistics_exactly(std):
    rng = np.random.default_rng(0)
    src = (0.6 + 0.03 * rng.normal(size=(40, 50, 3))).astype(np.float32)
    src[..., 2] *= 0.8  # a pink-grey "puppet"
    ref = (0.35 + 0.02 * rng.normal(size=(40, 50, 3))).astype(np.float32)
    ref[..., 0] += 0.15  # a darker, redder "driver" (both well inside the gamut: nothing clips)
    m_src = np.zeros((40, 50), bool)
    m_src[5:35, 5:30] = True
    m_ref = np.zeros((40, 50), bool)
    m_ref[10:38, 20:48] = True
    out = match_color_statistics(src, ref, m_src, m_ref, std=std)
    a, b = _lab(out)[m_src], _lab(ref)[m_ref]
    np.testing.assert_allclose(a.mean(axis=0), b.mean(axis=0), atol=0.05)
    if std:
        np.testing.assert_allclose(a.std(axis=0), b.std(axis=0), rtol=0.01, atol=0.05)
    else:  # the spread is the source's own
        np.testing.assert_allclose(a.std(axis=0), _lab(src)[m_src].std(axis=0), rtol=0.01, atol=0.05)
    assert np.abs(a.mean(axis=0) - _lab(src)[m_src].mean(axis=0)).max() > 5  # it did move


def test_lab_of_masked_pixels_equals_lab_of_the_whole_image():
    """match_color_statistics converts only the masked pixels to Lab: OpenCV must convert pixel
    by pixel (the same bits whatever the image's size and the pixel's position)."""
    rng = np.random.default_rng(3)
    for h, w in ((37, 53), (1, 1), (120, 101), (5, 3)):
        img = rng.uniform(-0.1, 1.1, (h, w, 3)).astype(np.float32)
        mask = rng.random((h, w)) < 0.6
        full = _lab(img)[mask]
        part = _lab(img[mask][None])[0]
        np.testing.assert_array_equal(part.view(np.uint32), full.view(np.uint32))


def test_colour_transfer_with_an_empty_mask_changes_nothing():
    src = np.full((8, 8, 3), 0.4, np.float32)
    out = match_color_statistics(src, src * 0.5, np.zeros((8, 8), bool))
    np.testing.assert_array_equal(out, src)


# ----------------------------------------------------------------------------- skin colour transfer
def _rgb(lab):
    return cv2.cvtColor(np.asarray(lab, np.float32), cv2.COLOR_Lab2RGB)


def _detail(h=40, w=48, amp=2.0):
    """A +-amp checkerboard in L (the persona's fine detail), zero in a and b."""
    yy, xx = np.mgrid[0:h, 0:w]
    d = np.zeros((h, w, 3), np.float32)
    d[..., 0] = amp * np.where((xx + yy) % 2 == 0, 1.0, -1.0)
    return d


def test_skin_colour_transfer_recovers_a_known_offset_and_gain():
    """sigma inf: out = median(ref) + (g, 1, 1) (src - median(src)) in Lab, g = the ratio of the
    skins' median lightness: a persona at L 45 with a +-2 L detail on a driver at L 60 (a, b
    shifted by +6, -4) comes out at 60 +- 2 x 60 / 45 with the driver's a, b (hand-computed)."""
    base = np.float32([45.0, 14.0, 20.0])  # a darker persona skin
    src_lab = base + _detail()
    ref_lab = np.broadcast_to(base + [15.0, 6.0, -4.0], src_lab.shape)
    src, ref = _rgb(src_lab), _rgb(ref_lab)
    skin = np.ones((40, 48), bool)
    out = _lab(transfer_skin_colour(src, ref, skin, skin, sigma=np.inf, gain=(2 / 3, 1.5)))
    # (OpenCV's float Lab round trip is good to ~0.1)
    np.testing.assert_allclose(out[..., 0], 60.0 + 60.0 / 45.0 * _detail()[..., 0], atol=0.3)
    np.testing.assert_allclose(out[..., 1:], np.broadcast_to([20.0, 16.0], out[..., 1:].shape), atol=0.3)


def test_skin_colour_transfer_clamps_the_gain_and_keeps_the_detail():
    base = np.float32([30.0, 14.0, 20.0])
    src_lab = base + _detail(amp=2.0)
    skin = np.ones((40, 48), bool)
    for ref_l, g in ((70.0, 1.5), (15.0, 2 / 3)):  # ratios 2.33 and 0.5: held at the bounds
        ref = _rgb(np.broadcast_to(np.float32([ref_l, 14.0, 20.0]), src_lab.shape))
        out = _lab(transfer_skin_colour(_rgb(src_lab), ref, skin, skin, sigma=np.inf, gain=(2 / 3, 1.5)))
        np.testing.assert_allclose(out[..., 0], ref_l + g * _detail(amp=2.0)[..., 0], atol=0.3)
    src = _rgb(src_lab)
    # with a smooth field: the low frequencies are the driver's, the fine detail the persona's
    yy, xx = np.mgrid[0:40, 0:48]
    ramp = np.zeros((40, 48, 3), np.float32)
    ramp[..., 0] = 10.0 * xx / 47.0  # the driver's lighting: brighter to the right
    ref = _rgb(base + [15.0, 4.0, 2.0] + ramp + _detail(amp=3.0)[:, ::-1])  # its own detail is not taken
    out = _lab(transfer_skin_colour(src, ref, skin, skin, sigma=3.0, gain=(1.0, 1.0)))
    low = cv2.GaussianBlur(out, (0, 0), 2.0)
    inner = (slice(8, -8), slice(8, -8))
    np.testing.assert_allclose(low[inner], cv2.GaussianBlur(_lab(ref), (0, 0), 2.0)[inner], atol=0.6)
    hp = out[..., 0] - cv2.GaussianBlur(out[..., 0], (0, 0), 1.5)
    hp_src = src_lab[..., 0] - cv2.GaussianBlur(src_lab[..., 0], (0, 0), 1.5)
    np.testing.assert_allclose(hp[inner], hp_src[inner], atol=0.3)


def test_skin_colour_transfer_takes_a_finer_field_where_its_weight_is():
    """A persona with two soft bumps (+2.5 L*, Gaussian sigma 5 px: within the fields' outlier trim)
    on a flat driver, gain 1: with the field at sigma inf both are detail and kept; with ``fine``
    (weight 1 on the left half, sigma 1.5) the left one is the field's there and takes the driver's
    flat skin, the right one stays."""
    h, w = 40, 96
    yy, xx = np.mgrid[0:h, 0:w]
    bumps = sum(2.5 * np.exp(-((xx - cx) ** 2 + (yy - 20) ** 2) / (2 * 5.0 ** 2)) for cx in (24, 72))
    src_lab = np.float32([45.0, 14.0, 20.0]) + np.stack([bumps, 0 * bumps, 0 * bumps], -1).astype(np.float32)
    ref = _rgb(np.broadcast_to(np.float32([45.0, 14.0, 20.0]), src_lab.shape))
    skin = np.ones((h, w), bool)
    left = np.zeros((h, w), np.float32)
    left[:, :48] = 1.0
    plain = _lab(transfer_skin_colour(_rgb(src_lab), ref, skin, skin, sigma=np.inf, gain=(1.0, 1.0)))
    fine = _lab(transfer_skin_colour(_rgb(src_lab), ref, skin, skin, sigma=np.inf, gain=(1.0, 1.0),
                                     fine=(left, 1.5)))
    assert plain[20, 24, 0] - plain[20, 5, 0] == pytest.approx(2.5, abs=0.3)
    assert fine[20, 24, 0] - fine[20, 5, 0] < 0.4  # the left bump is gone
    assert fine[20, 72, 0] - fine[20, 90, 0] == pytest.approx(2.5, abs=0.3)  # the right one is kept


def test_skin_colour_transfer_ignores_what_is_not_skin():
    """A dark brow and a dark lid on the persona (outside its skin mask) and the driver's dark
    fringe (outside its skin mask) do not move the colour of the skin."""
    base = np.float32([45.0, 14.0, 20.0])
    src_lab = base + _detail()
    ref_lab = base + [20.0, 2.0, -2.0] + _detail()
    src, ref = _rgb(src_lab), _rgb(ref_lab)
    skin = np.ones((40, 48), bool)
    plain = _lab(transfer_skin_colour(src, ref, skin, skin, sigma=6.0))
    src2, ref2 = src.copy(), ref.copy()
    src2[10:16, 8:40] = 0.05  # the persona's brow
    ref2[0:8] = (0.2, 0.12, 0.05)  # the driver's fringe
    s_skin, r_skin = skin.copy(), skin.copy()
    s_skin[10:16, 8:40] = False
    r_skin[0:8] = False
    out = _lab(transfer_skin_colour(src2, ref2, s_skin, r_skin, sigma=6.0))
    keep = s_skin & r_skin
    np.testing.assert_allclose(out[keep], plain[keep], atol=0.5)
    # the brow stays darker than the skin around it (detail kept, not bleached)
    assert out[12, 20, 0] < out[24, 20, 0] - 20


def test_skin_low_pass_trims_outliers_and_falls_back_to_the_median():
    lab = np.zeros((30, 30, 3), np.float32)
    lab[:] = (60.0, 10.0, 15.0)
    lab[5, 5] = (0.0, 0.0, 0.0)  # one black stray hair in the mask
    skin = np.zeros((30, 30), bool)
    skin[:, :15] = True
    low, med = skin_low_pass(lab, skin, 2.0)
    np.testing.assert_allclose(med, (60.0, 10.0, 15.0))
    # clipped to the median - 3 x the spread (floored at 1): the black pixel pulls its
    # neighbourhood down by < 0.15 L, not by the ~2.4 of a plain average
    assert low[5, 5, 0] > 59.85
    den = np.maximum(cv2.GaussianBlur(skin.astype(np.float32), (0, 0), 2.0), 1e-6)[..., None]
    naive = cv2.GaussianBlur(lab * skin[..., None], (0, 0), 2.0) / den
    assert naive[5, 5, 0] < 58.0
    np.testing.assert_allclose(low[:, 25:], np.broadcast_to(med, low[:, 25:].shape), atol=1e-3)  # far from skin


def test_persona_colour_keeps_the_skin_tone_and_takes_the_lighting():
    """colour="persona": linear R, G, B multiplied by the driver's low-frequency luminance ratio
    (a left-right gradient) over the persona's (flat): the persona's chromaticity is kept."""
    base = np.float32([45.0, 14.0, 20.0])
    src_lab = base + _detail(amp=1.0)
    yy, xx = np.mgrid[0:40, 0:48]
    ref_lab = np.zeros((40, 48, 3), np.float32)
    ref_lab[:] = (70.0, 8.0, 12.0)
    ref_lab[..., 0] += 8.0 * (xx - 23.5) / 23.5  # lighting from the right
    src, ref = _rgb(src_lab), _rgb(ref_lab)
    skin = np.ones((40, 48), bool)
    out = transfer_skin_colour(src, ref, skin, skin, sigma=2.0, colour="persona")
    inner = (slice(8, -8), slice(8, -8))
    lin_o, lin_s, lin_r = srgb_to_linear(out), srgb_to_linear(src), srgb_to_linear(ref)
    chrom = lambda x: x / x.sum(axis=2, keepdims=True)  # noqa: E731
    np.testing.assert_allclose(chrom(lin_o)[inner], chrom(lin_s)[inner], atol=2e-3)
    luma = np.float32([0.2126, 0.7152, 0.0722])
    y_r = cv2.GaussianBlur(lin_r @ luma, (0, 0), 2.0)
    ratio = cv2.GaussianBlur(lin_o @ luma, (0, 0), 2.0) / cv2.GaussianBlur(lin_s @ luma, (0, 0), 2.0)
    np.testing.assert_allclose(ratio[inner], (y_r / np.median(y_r))[inner], rtol=0.03)
    with pytest.raises(BadInputError, match="colour"):
        transfer_skin_colour(src, ref, skin, skin, sigma=2.0, colour="grey")


# ----------------------------------------------------------------------------- occlusion
@pytest.fixture(scope="module")
def driver_face():
    """A real face (FRL 004) at about a GRID face's size (~100 px wide), its landmarks and oval."""
    from facetex._resources import sample_path
    from facetex.geometry.skin import face_region_mask
    from facetex.landmarks import detect_face, face_mesh468
    from facetex.puppet.composite import FACE_OVAL

    img = cv2.imread(str(sample_path("frl_004_neutral.jpg")))[..., ::-1].astype(np.float32) / 255.0
    f = detect_face(img)
    mesh = face_mesh468(img, f)
    k = 100.0 / np.linalg.norm(f.points68[16] - f.points68[0])
    small = cv2.resize(img, None, fx=k, fy=k, interpolation=cv2.INTER_AREA)
    p = (f.points68 + 0.5) * k - 0.5
    oval = (mesh[list(FACE_OVAL), :2] + 0.5) * k - 0.5
    region = face_region_mask(p, small.shape, mesh=(mesh + 0.5) * k - 0.5)
    return small, p, oval, region


def _fringe(img, p, region):
    """The image with a dark-brown fringe over the forehead down to just above the brows."""
    band = region.copy()
    band[int(p[17:27, 1].min() - 4):] = False
    out = img.copy()
    out[band] = (0.2, 0.13, 0.08)
    return out, band


def test_occlusion_mask_finds_a_fringe_and_not_the_features_or_a_mole(driver_face):
    img, p, _, region = driver_face
    hair, band = _fringe(img, p, region)
    c = np.round(p[[2, 31, 41, 48]].mean(0)).astype(int)
    hair[c[1] - 1:c[1] + 1, c[0] - 1:c[0] + 1] = (0.25, 0.15, 0.1)  # a mole on the cheek
    skin, feats = skin_pixels(hair, p, region)
    occ = occlusion_mask(region, skin, feats, p)
    assert occ.dtype == np.float32 and occ.shape == region.shape
    assert occ[band].mean() > 0.95  # the fringe stays in front
    assert occ[c[1] - 3:c[1] + 4, c[0] - 3:c[0] + 4].max() == 0.0  # the mole is skin
    for i in (37, 44, 51, 57, 33):  # eyes, mouth, nose: the puppet replaces them
        x, y = np.round(p[i]).astype(int)
        assert occ[y, x] == 0.0
    assert occ[~region].max() == 0.0
    # the same face without a fringe: nothing occludes it
    skin0, feats0 = skin_pixels(img, p, region)
    assert occlusion_mask(region, skin0, feats0, p).mean() < 0.01


def test_outline_band_is_the_regions_edge_within_reach():
    """A 40 x 40 square face region of face width 100 (jaw ends 100 px apart): reach 0.03 is a
    3 px disc, so the band is everything but the square eroded by 3 px."""
    from facetex.puppet.occluders import outline_band

    region = np.zeros((60, 60), bool)
    region[10:50, 10:50] = True
    p = np.zeros((68, 2))
    p[16] = (100.0, 0.0)
    band = outline_band(region, p, reach=0.03)
    assert band[0, 0] and band[10, 30] and band[12, 30]  # outside, on the edge, 2 px in
    assert not band[13, 30] and not band[30, 30]  # 3 px in (the 3 px disc's reach ends), the middle
    assert band.sum() == 60 * 60 - 34 * 34


def test_occlusion_mask_leaves_a_highlight_apart_from_the_outline(driver_face):
    """A pale, whitish patch on the nose (a driver's specular highlight, as big as a fringe's piece)
    is the face's own when pieces must reach the outline (``touching``); the fringe still counts."""
    from facetex.puppet.occluders import outline_band

    img, p, _, region = driver_face
    hair, band = _fringe(img, p, region)
    yy, xx = np.mgrid[:region.shape[0], :region.shape[1]]
    c = p[[28, 30]].mean(0)
    shine = (xx - c[0]) ** 2 + (yy - c[1]) ** 2 <= 3.5 ** 2
    hair[shine] = (0.97, 0.93, 0.92)
    skin, feats = skin_pixels(hair, p, region)
    assert (shine & ~skin & ~feats).sum() > 20  # not skin-coloured: a piece
    loose = occlusion_mask(region, skin, feats, p, min_size=0.02)
    held = occlusion_mask(region, skin, feats, p, min_size=0.02, touching=outline_band(region, p))
    assert loose[shine].mean() > 0.9  # without the rule the highlight stood in front of the puppet
    assert held[shine].max() == 0.0
    assert held[band].mean() > 0.95


def test_composite_keeps_the_drivers_fringe_in_front(driver_face):
    img, p, oval, region = driver_face
    hair, band = _fringe(img, p, region)
    puppet = np.empty_like(img)
    puppet[:] = (0.45, 0.3, 0.22)  # a darker persona
    coverage = region.astype(np.float32)
    kw = dict(driver_oval=oval, driver_points68=p)
    out, alpha = composite_face(hair, puppet, coverage, None, params=CompositeParams(mouth=False), **kw)
    off = composite_face(hair, puppet, coverage, None, params=CompositeParams(mouth=False, occlusion=False), **kw)[1]
    # the part of the fringe the puppet would cover without the occlusion mask (inside the outline)
    covered = band & (cv2.erode(band.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0) & (off > 0.9)
    assert covered.sum() > 100
    assert alpha[covered].max() < 0.02
    np.testing.assert_allclose(out[covered], hair[covered], atol=0.02)
    c = np.round(p[[2, 31, 41, 48]].mean(0)).astype(int)
    assert alpha[c[1], c[0]] > 0.99  # the cheeks are the puppet's
    # a whitish highlight on the driver's nose lies apart from the outline: the puppet covers it
    shiny = hair.copy()
    yy, xx = np.mgrid[:region.shape[0], :region.shape[1]]
    m = p[[28, 30]].mean(0)
    shine = (xx - m[0]) ** 2 + (yy - m[1]) ** 2 <= 3.5 ** 2
    shiny[shine] = (0.97, 0.93, 0.92)
    alpha2 = composite_face(shiny, puppet, coverage, None, params=CompositeParams(mouth=False), **kw)[1]
    assert alpha2[shine].min() > 0.99 and alpha2[covered].max() < 0.02



def _temple_hair(img, p, region):
    """The image with dark-brown hair over its left temple (left of the brow's outer end, above the
    lower lids) and the same colour as a beard below the mouth: (image, temple, beard)."""
    yy, xx = np.mgrid[:region.shape[0], :region.shape[1]]
    temple = region & (xx < p[17, 0] + 2) & (yy < p[36:42, 1].max())
    beard = region & (yy > p[57, 1] + 3)
    out = img.copy()
    out[temple | beard] = (0.2, 0.13, 0.08)
    return out, temple, beard


def test_persona_hair_finds_hair_over_the_temples_not_a_beard_or_the_features(driver_face):
    """A persona face with hair over one temple (as in most of a collection's photos) and a beard:
    the temple is the persona's hair, the beard (below the lower lids) and the features are not;
    the same face without them: only the model's own hair at his left temple's edge."""
    from facetex.puppet.composite import persona_hair

    img, p, _, region = driver_face
    hairy, temple, beard = _temple_hair(img, p, region)
    assert temple.sum() > 40 and beard.sum() > 40
    h = persona_hair(hairy, p, region)
    assert h.dtype == np.float32 and h.shape == region.shape
    feats = skin_pixels(hairy, p, region)[1]  # (hair inside the brows' grown masks is not judged)
    assert h[temple & ~feats].min() > 0.95 and h[temple].mean() > 0.75
    assert h[beard].max() == 0.0 and h[~region].max() == 0.0
    for i in (37, 44, 51, 57, 33, 19, 24):  # eyes, mouth, nose, brows
        x, y = np.round(p[i]).astype(int)
        assert h[y, x] == 0.0
    clean = persona_hair(img, p, region)  # only the model's own hair, at the edge of his left temple
    assert clean.sum() < 0.015 * region.sum()
    assert np.nonzero(clean > 0.5)[1].max() < p[17, 0] + 2


def test_persona_hair_leaves_dark_lids_apart_from_the_outline(driver_face):
    """A dark patch over each inner upper lid (a dark-skinned persona's shaded lids and brow heads,
    hair-coloured, each larger than a piece's minimum) is not hair: it does not reach the face's
    outline; the temple's hair in the same face still is."""
    from facetex.puppet.composite import persona_hair

    img, p, _, region = driver_face
    hairy, temple, _ = _temple_hair(img, p, region)
    yy, xx = np.mgrid[:region.shape[0], :region.shape[1]]
    iod = float(np.linalg.norm(p[45] - p[36]))
    lids = np.zeros(region.shape, bool)
    for a, b in ((38, 20), (43, 23)):  # between the upper lid and the brow
        c = 0.5 * (p[a] + p[b])
        lids |= (xx - c[0]) ** 2 + (yy - c[1]) ** 2 <= (0.12 * iod) ** 2
    hairy[lids] = (0.2, 0.13, 0.08)
    h = persona_hair(hairy, p, region)
    feats = skin_pixels(hairy, p, region)[1]
    assert (lids & ~feats).sum() > 20
    assert h[lids].max() < 0.05
    assert h[temple & ~feats].min() > 0.95


def test_persona_hair_follows_a_strand_into_the_brows_grown_mask_but_leaves_the_brows(driver_face):
    """A thin strand of dark hair from beyond the face's outline (over the temple, inside the
    rendered face's ``area``) down to the outer end of the right brow (the model has hair of his
    own at his left temple), as in Arroyo's photos: inside
    the outline it is too small a piece to count, so it showed as a dark streak; followed through
    ``area`` it is hair, up to the brow's own band (not its grown mask). A dark fringe of the brow's
    own (a ribbon along its upper edge, inside its grown mask only) and the brow's band are not."""
    import dataclasses

    from facetex.geometry.skin import SkinParams, brow_mask, feature_mask
    from facetex.puppet.composite import persona_hair

    img, p, _, region = driver_face
    h, w = region.shape
    yy, xx = np.mgrid[:h, :w]
    area = cv2.dilate(region.view(np.uint8), np.ones((31, 31), np.uint8)) > 0
    tight = dataclasses.replace(SkinParams(), brow_margin=0.0)
    band = brow_mask(p, (h, w), tight)
    grown = brow_mask(p, (h, w))
    iod = float(np.linalg.norm(p[45] - p[36]))
    a = p[26]
    b = a + (0.5 * iod, -0.7 * iod)  # up and out over the temple, beyond the outline
    strand = cv2.line(np.zeros((h, w), np.uint8), tuple(np.round(a).astype(int)), tuple(np.round(b).astype(int)),
                      1, thickness=2) > 0
    fringe = grown & ~band & (yy < p[22:27, 1].min()) & (xx < p[24, 0])
    hairy = img.copy()
    hairy[(strand & area) | fringe] = (0.2, 0.13, 0.08)
    inside = strand & region & ~feature_mask(p, (h, w), tight)
    assert inside.sum() >= 3 and (strand & area & ~region).sum() > 20 and fringe.sum() > 10
    with_area = persona_hair(hairy, p, region, area=area)
    alone = persona_hair(hairy, p, region)
    assert with_area[inside].min() > 0.9 and alone[inside].max() < 0.5
    # the brow's own edge is not a piece on its own (a pixel or two at the outline's edge is grazed)
    assert np.mean(with_area[fringe] < 0.05) > 0.95
    core = cv2.erode(band.view(np.uint8), np.ones((5, 5), np.uint8)) > 0
    core &= xx < p[25, 0]  # away from the strand's end
    assert with_area[core].max() < 0.05
    assert with_area[~region].max() == 0.0


def test_composite_shows_the_driver_where_the_persona_has_hair(driver_face):
    """The rendered puppet with hair over a temple on a driver without: the driver's frame shows
    there (alpha ~0) with ``persona_hair``, the puppet's hair without it; the cheeks are the puppet's."""
    img, p, oval, region = driver_face
    puppet, temple, _ = _temple_hair(img * np.float32([0.8, 0.7, 0.65]), p, region)  # a darker persona
    coverage = region.astype(np.float32)
    kw = dict(driver_oval=oval, driver_points68=p, puppet_points68=p)
    _, alpha = composite_face(img, puppet, coverage, None, params=CompositeParams(mouth=False, eyes="persona"), **kw)
    off = composite_face(img, puppet, coverage, None, params=CompositeParams(mouth=False, eyes="persona",
                                                                             persona_hair=False), **kw)[1]
    inner = temple & (off > 0.9) & ~skin_pixels(puppet, p, region)[1]
    assert inner.sum() > 20
    assert alpha[inner].max() < 0.05
    c = np.round(p[[2, 31, 41, 48]].mean(0)).astype(int)
    assert alpha[c[1], c[0]] > 0.99 and off[c[1], c[0]] > 0.99


def test_composite_keeps_the_puppets_eyeballs_where_the_puppet_draws_them(driver_face):
    """A pale persona (flat skin, white eyeballs) drawn with its eyes 0.15 eye distances above the
    driver's (its landmarks ``puppet_points68``) on a dark driver: the eyeballs keep their lightness
    at the puppet's eyes; inside the driver's eye outlines below them the puppet's skin takes the
    driver's tone (kept at the driver's landmarks it was a pale crescent under each eye)."""
    from facetex.geometry.masks import polygon_mask

    img, p, oval, region = driver_face
    driver = img * np.float32(0.35)
    iod = float(np.linalg.norm(p[36] - p[45]))
    pp = p.copy()
    pp[36:48, 1] -= 0.15 * iod
    eyes = lambda q: np.maximum(polygon_mask(q[36:42], region.shape), polygon_mask(q[42:48], region.shape)) > 0.5
    puppet = np.empty_like(img)
    puppet[:] = (0.85, 0.7, 0.62)
    puppet[eyes(pp)] = (0.95, 0.95, 0.95)
    coverage = region.astype(np.float32)
    out, _ = composite_face(driver, puppet, coverage, None, driver_oval=oval, driver_points68=p, puppet_points68=pp,
                            params=CompositeParams(mouth=False, eyes="persona", sharpen=1.0, grain=0.0,
                                                   nose_sharpen=1.0, persona_hair=False))
    below = eyes(p) & ~(cv2.dilate(eyes(pp).view(np.uint8), np.ones((9, 9), np.uint8)) > 0)
    core = cv2.erode(eyes(pp).view(np.uint8), np.ones((3, 3), np.uint8)) > 0
    assert below.sum() > 10 and core.sum() > 10
    lo, pu = _lab(out), _lab(puppet)
    assert np.median(lo[below][:, 0]) < np.median(pu[below][:, 0]) - 20  # the driver's dark tone
    assert np.median(lo[core][:, 0]) > np.median(lo[below][:, 0]) + 25  # the eyeballs stay light


def test_composite_keeps_the_drivers_glasses_rims_in_front(driver_face):
    img, p, oval, region = driver_face
    puppet = np.empty_like(img)
    puppet[:] = (0.45, 0.3, 0.22)
    coverage = region.astype(np.float32)
    rims = np.zeros(region.shape, np.float32)
    y = int(round(p[41, 1] + 0.1 * np.linalg.norm(p[36] - p[45])))  # a line under the right eye
    rims[y:y + 2, int(p[36, 0]):int(p[39, 0])] = 1.0
    kw = dict(driver_oval=oval, driver_points68=p, params=CompositeParams(mouth=False))
    out, alpha = composite_face(img, puppet, coverage, None, rims=rims, **kw)
    without = composite_face(img, puppet, coverage, None, **kw)[1]
    on = (rims > 0) & (without > 0.9)
    assert on.sum() >= 10
    assert alpha[on].max() < 0.02
    np.testing.assert_allclose(out[on], img[on], atol=0.02)
    np.testing.assert_allclose(alpha[~(cv2.dilate(rims, np.ones((9, 9))) > 0)],
                               without[~(cv2.dilate(rims, np.ones((9, 9))) > 0)], atol=1e-6)
    off = composite_face(img, puppet, coverage, None, rims=rims, driver_oval=oval, driver_points68=p,
                         params=CompositeParams(mouth=False, occlusion=False))[1]
    assert off[on].min() > 0.9  # occlusion off: the rims too

# ----------------------------------------------------------------------------- lighting
def test_sh_fit_recovers_the_lighting_despite_outliers():
    n, inside = _sphere_normals()
    true = np.array([[0.5, 0.45, 0.4], [0.2, 0.1, 0.05], [-0.1, -0.1, -0.1], [-0.15, -0.2, -0.1]], np.float32)
    img = sh_shading(n, true)
    img[20:26, 20:40] = 0.02  # a dark eyebrow: not shading
    fit = fit_sh_lighting(img, n, inside)
    np.testing.assert_allclose(fit, true, atol=0.02)
    plain = np.linalg.lstsq(np.c_[np.ones(inside.sum()), n[inside]], img[inside], rcond=None)[0]
    assert np.abs(plain - true).max() > 2 * np.abs(fit - true).max()  # least squares alone is pulled off


def test_relight_moves_one_lighting_to_another():
    n, inside = _sphere_normals()
    l_src = np.array([[0.5] * 3, [0.25] * 3, [0.0] * 3, [-0.1] * 3], np.float32)  # light from the right
    l_dst = np.array([[0.45] * 3, [-0.2] * 3, [-0.05] * 3, [-0.1] * 3], np.float32)  # from the left
    albedo = np.float32([0.9, 0.7, 0.6])
    src = albedo * sh_shading(n, l_src)
    out = relight(src, n, l_src, l_dst, limits=(0.01, 100.0), floor=0.0)
    ok = inside & (sh_shading(n, l_src)[..., 0] > 0.05)
    np.testing.assert_allclose(out[ok], (albedo * sh_shading(n, l_dst))[ok], rtol=1e-4, atol=1e-5)


def test_srgb_round_trip():
    x = np.linspace(0, 1, 101, dtype=np.float32)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=1e-5)
    assert srgb_to_linear(np.float32(0.5)) == pytest.approx(0.2140, abs=1e-3)


# ----------------------------------------------------------------------------- blending and masks
def test_poisson_blend_takes_the_border_from_the_destination():
    rng = np.random.default_rng(1)
    yy, xx = np.mgrid[0:60, 0:70].astype(np.float32)
    dst = np.stack([0.3 + 0.004 * xx, 0.4 + 0.003 * yy, 0.5 + 0.0 * xx], axis=-1)
    dst += 0.01 * rng.normal(size=dst.shape).astype(np.float32)
    bump = 0.2 * np.exp(-((xx - 35) ** 2 + (yy - 30) ** 2) / 40.0)[..., None]
    src = dst + 0.25 + bump  # a brighter copy with a feature in the middle
    mask = _disc(60, 70, 35, 30, 22)
    out = poisson_blend(np.clip(src, 0, 1), np.clip(dst, 0, 1), mask)
    np.testing.assert_array_equal(out[~mask], np.clip(dst, 0, 1)[~mask])  # outside: the destination
    # a constant offset has no gradient: it is removed entirely, the feature stays
    inner = _disc(60, 70, 35, 30, 19)
    np.testing.assert_allclose(out[inner], np.clip(dst + bump, 0, 1)[inner], atol=0.012)


def test_poisson_blend_is_opencvs_normal_clone_in_float():
    # on 8-bit inputs the float solve is seamlessClone's (which truncates its result to 8 bits)
    rng = np.random.default_rng(2)
    yy, xx = np.mgrid[0:50, 0:64]
    src8 = np.clip(120 + 60 * np.sin(xx / 6.0) + 30 * np.cos(yy / 4.0) + rng.normal(0, 3, (50, 64)), 0, 255)
    src8 = np.repeat(src8[..., None], 3, axis=-1).astype(np.uint8)
    src8[..., 1] //= 2
    dst8 = np.clip(rng.normal(70, 20, (50, 64, 3)), 0, 255).astype(np.uint8)
    mask = ((yy - 24) / 17.0) ** 2 + ((xx - 30) / 23.0) ** 2 < 1
    out = poisson_blend(src8 / np.float32(255), dst8 / np.float32(255), mask)
    x, y, w, h = cv2.boundingRect(mask.astype(np.uint8))
    clone = cv2.seamlessClone(src8, dst8, mask.astype(np.uint8) * 255, (x + w // 2, y + h // 2), cv2.NORMAL_CLONE)
    gap = out[mask] * 255 - clone[mask]
    assert gap.min() > -0.01 and gap.max() < 1.01  # truncation: up to one level below
    assert 0.3 < gap.mean() < 0.7


def test_poisson_blend_is_continuous_in_its_inputs():
    # no 8-bit rounding inside: a change far below 1/255 moves the result by as little
    rng = np.random.default_rng(3)
    src = rng.uniform(0.2, 0.8, (40, 48, 3)).astype(np.float32)
    dst = rng.uniform(0.2, 0.8, (40, 48, 3)).astype(np.float32)
    mask = _disc(40, 48, 24, 20, 15)
    nudged = src + np.float32(1e-5) * rng.choice([-1, 1], src.shape).astype(np.float32)
    d = np.abs(poisson_blend(nudged, dst, mask) - poisson_blend(src, dst, mask))
    assert d.max() < 3e-5


def test_skin_colour_transfer_is_continuous_in_the_puppet():
    # the colour transfer's CIELAB must not step: a puppet changed by 1e-5 (far below 1/255)
    # comes out changed by about as little (OpenCV's float sRGB->Lab table made 1/255 jumps)
    rng = np.random.default_rng(4)
    src = rng.uniform(0.05, 0.6, (1, 4000, 3)).astype(np.float32)
    ref = rng.uniform(0.4, 0.9, (1, 4000, 3)).astype(np.float32)
    skin = np.ones((1, 4000), bool)
    out = transfer_skin_colour(src, ref, skin, skin, sigma=3.0)
    nudged = transfer_skin_colour(src + np.float32(1e-5), ref, skin, skin, sigma=3.0)
    assert np.abs(nudged - out).max() < 1e-4


def test_poisson_blend_checks_sizes():
    with pytest.raises(BadInputError):
        poisson_blend(np.zeros((8, 8, 3)), np.zeros((9, 8, 3)), np.ones((8, 8), bool))


def test_polygon_mask_area_and_antialiasing():
    sq = np.array([[10.25, 10.25], [40.25, 10.25], [40.25, 30.25], [10.25, 30.25]])
    m = polygon_mask(sq, (50, 50))
    assert m.sum() == pytest.approx(30 * 20, rel=0.015)
    assert ((m > 0.05) & (m < 0.95)).any()  # fractional coverage at the edges


def test_inner_feather_stays_inside_the_mask():
    mask = _disc(r=20)
    a = inner_feather(mask, 5.0)
    assert a[~mask].max() == 0.0
    assert a[32, 32] == pytest.approx(1.0)
    row = a[32, 12:33]  # from the edge towards the centre: rises monotonically
    assert np.all(np.diff(row) >= -1e-6) and row[0] < 0.2


# ----------------------------------------------------------------------------- boundary step
def test_boundary_step_of_a_known_colour_edge():
    mask = _disc(r=20)
    lab = np.zeros((64, 64, 3), np.float32)
    lab[..., 0] = np.where(mask, 50.0, 60.0)  # grey 50 inside, grey 60 outside: ΔE 10
    img = cv2.cvtColor(lab, cv2.COLOR_Lab2RGB)
    mean, sectors = boundary_color_step(img, mask, band=3, gap=1, sectors=8)
    assert mean == pytest.approx(10.0, abs=0.2)
    np.testing.assert_allclose(sectors, 10.0, atol=0.3)
    # the same image measured at an edge that does not exist there: no step
    flat = boundary_color_step(img, _disc(r=10), band=3, gap=1, sectors=8)[0]
    assert flat < 0.5


def test_boundary_step_sees_local_breaks_a_global_mean_would_cancel():
    mask = _disc(r=20)
    lab = np.full((64, 64, 3), 55.0, np.float32)
    lab[..., 1:] = 0
    inside_top = mask & (np.mgrid[0:64, 0:64][0] < 32)
    lab[..., 0] = np.where(inside_top, 63.0, np.where(mask, 47.0, 55.0))  # +8 on top, -8 below
    img = cv2.cvtColor(lab, cv2.COLOR_Lab2RGB)
    assert boundary_color_step(img, mask, band=3, sectors=16)[0] > 6.0


# ----------------------------------------------------------------------------- mouth interior
def test_mouth_interior_moves_the_drivers_mouth_into_the_puppets_lips():
    h, w = 80, 100
    frame = np.full((h, w, 3), 0.7, np.float32)
    d_lips = np.array([[20, 30], [27, 25], [35, 24], [43, 25], [50, 30], [43, 35], [35, 36], [27, 35]], float)
    cv2.fillPoly(frame, [np.round(d_lips).astype(np.int32)], (0.1, 0.0, 0.2))  # dark purple interior
    # the puppet's mouth: elsewhere, wider, opened less
    p_lips = d_lips.copy()
    p_lips[:, 0] = 50 + (d_lips[:, 0] - 35) * 1.3
    p_lips[:, 1] = 55 + (d_lips[:, 1] - 30) * 0.7
    img, alpha = mouth_interior(frame, d_lips, p_lips, cavity=None)
    core = alpha > 0.99
    assert core.sum() > 50
    np.testing.assert_allclose(img[core], np.broadcast_to([0.1, 0.0, 0.2], img[core].shape), atol=0.02)
    assert alpha[:40].max() == 0  # nothing where the puppet's mouth is not
    # the puppet's lips closed: no interior
    closed = p_lips.copy()
    closed[5:, 1] = closed[[3, 2, 1], 1]
    assert mouth_interior(frame, d_lips, closed)[1].sum() < 0.05 * core.sum()
    # the driver's lips closed: nothing to show either (its lip sliver would draw a red line)
    shut = d_lips.copy()
    shut[5:, 1] = shut[[3, 2, 1], 1] + 0.5
    assert mouth_interior(frame, shut, p_lips)[1].max() == 0



def _teeth_mouth(scale: float):
    """A driver's frame whose open mouth (inner lips 60-67 scaled by ``scale``) is white teeth from
    lip to lip, the lips red round it; the puppet's lips the same."""
    lips = np.array([[-15, 0], [-8, -6], [0, -7], [8, -6], [15, 0], [8, 6], [0, 7], [-8, 6]], float) * scale
    lips += [6 * scale + 20, 4 * scale + 20]
    h, w = int(8 * scale + 40), int(12 * scale + 40)
    frame = np.zeros((h, w, 3), np.float32)
    frame[:] = (0.55, 0.15, 0.15)
    cv2.fillPoly(frame, [np.round(lips * 16).astype(np.int32)], (0.95, 0.95, 0.92), shift=4)
    return frame, lips


def _teeth_rows(img, alpha, lips) -> float:
    """The fraction of the opening's height down its middle column that shows the teeth."""
    x = int(round(lips[[2, 6], 0].mean()))
    y0, y1 = int(np.ceil(lips[2, 1])), int(np.floor(lips[6, 1]))
    col = (img[y0:y1 + 1, x] * alpha[y0:y1 + 1, x, None]).mean(axis=-1)
    return float((col > 0.8).sum()) / (lips[6, 1] - lips[2, 1])


def test_mouth_interior_margin_is_capped_with_its_soft_edge():
    """On a large mouth (the soft edge capped at a few px) the driver's teeth, lip to lip, fill the
    puppet's opening up to that edge instead of 1 / inset of it under a dark band; a small mouth
    (its ramp not capped) samples the driver's interior exactly as without the cap."""
    frame, lips = _teeth_mouth(4.0)  # a 56 px gap: the ramp is capped
    capped = _teeth_rows(*mouth_interior(frame, lips, lips), lips)
    uncapped = _teeth_rows(*mouth_interior(frame, lips, lips, soft_px=None), lips)
    assert capped > 0.8 > uncapped
    frame, lips = _teeth_mouth(0.6)  # an 8 px gap: nothing changes
    a, b = mouth_interior(frame, lips, lips), mouth_interior(frame, lips, lips, soft_px=1e6)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])

def test_pchip_matches_scipy():
    from scipy.interpolate import PchipInterpolator

    from facetex.puppet._contours import _pchip

    rng = np.random.default_rng(0)
    for n in (2, 3, 5, 8):
        for _ in range(20):
            x = np.sort(rng.uniform(-10, 10, n)) + np.arange(n) * 0.1  # strictly increasing
            y = rng.normal(0, 3, n)
            t = np.linspace(x[0] - 1, x[-1] + 1, 101)
            np.testing.assert_allclose(_pchip(x, y)(t), PchipInterpolator(x, y)(t), atol=1e-6)


def _mouths():
    """A driver frame with a wide-open mouth (inner lips 60-67) whose interior is white teeth in
    the upper third, a dark cavity below; lips around it; and a puppet mouth elsewhere, wider and
    opened less."""
    h, w = 120, 160
    frame = np.full((h, w, 3), (0.8, 0.6, 0.5), np.float32)  # skin
    d = np.array([[30, 40], [45, 30], [60, 28], [75, 30], [90, 40], [75, 52], [60, 54], [45, 52]], float)
    outer = d.copy()
    outer[:, 1] = 40 + (d[:, 1] - 40) * 1.8
    outer[:, 0] = 60 + (d[:, 0] - 60) * 1.15
    cv2.fillPoly(frame, [np.round(outer).astype(np.int32)], (0.75, 0.3, 0.3))  # red lips
    inner = np.zeros((h, w), np.uint8)
    cv2.fillPoly(inner, [np.round(d).astype(np.int32)], 1)
    yy = np.mgrid[0:h, 0:w][0]
    frame[(inner > 0) & (yy < 35)] = (0.95, 0.95, 0.9)  # teeth
    frame[(inner > 0) & (yy >= 35)] = (0.1, 0.02, 0.05)  # cavity
    p = np.empty_like(d)
    p[:, 0] = 100 + (d[:, 0] - 60) * 1.4
    p[:, 1] = 90 + (d[:, 1] - 40) * 0.8
    return frame, d, p


def test_sample_between_inset_scales_across_the_opening_but_not_beyond_the_corners():
    """A frame that holds its own coordinates: at inset 1 the puppet's opening samples the driver's
    between its inner lips; at 1.3 its upper and lower edges sample 15 % of the driver's gap beyond
    them (the lips, keyed out later), while along the corner line it stays inside the corners."""
    from facetex.puppet._contours import sample_between

    _, d, p = _mouths()
    yy, xx = np.mgrid[0:120, 0:160].astype(np.float32)
    coords = np.stack([xx, yy, np.zeros_like(xx)], axis=-1)
    col = 100  # the puppet's middle column (the driver's middle: x 60)
    for inset in (1.0, 1.3):
        s = sample_between(coords, d, p, (120, 160), inset=inset)
        x0, y0, x1, y1 = s.box
        w = s.warped
        rows = np.flatnonzero(s.gap[:, col - x0] > 0)
        top, bottom = w[rows[0], col - x0, 1], w[rows[-1], col - x0, 1]
        gap = 54 - 28  # the driver's inner-lip gap in its middle column (y 28 .. 54)
        if inset == 1.0:
            assert top == pytest.approx(28, abs=1.5) and bottom == pytest.approx(54, abs=1.5)
        else:
            assert top == pytest.approx(28 - 0.15 * gap, abs=1.5)
            assert bottom == pytest.approx(54 + 0.15 * gap, abs=1.5)
        inside = s.depth > 0
        assert w[..., 0][inside].min() >= 30 - 0.5 and w[..., 0][inside].max() <= 90 + 0.5  # the corners


def test_mouth_interior_puts_teeth_and_cavity_where_they_are_in_the_drivers_mouth():
    frame, d, p = _mouths()
    img, alpha = mouth_interior(frame, d, p, cavity=None)
    core = alpha > 0.9
    assert core.sum() > 100
    lum = img[:, 100].mean(axis=1)  # the middle column, top to bottom
    rows = np.nonzero(alpha[:, 100] > 0.5)[0]
    a, b = rows.min(), rows.max()
    assert lum[a: a + 2].mean() > 0.8  # the upper teeth under the puppet's upper lip
    assert lum[b - 6: b + 1].mean() < 0.15  # the dark cavity above its lower lip
    assert alpha[:70].max() == 0  # nothing outside the puppet's mouth


def test_mouth_interior_alpha_is_soft_and_smooth_under_the_puppets_lips():
    frame, d, p = _mouths()
    _, alpha = mouth_interior(frame, d, p, cavity=None)
    # soft: across the mouth's middle column alpha rises over several pixels, not one
    col = alpha[:, 100]
    ramp = (col > 0.02) & (col < 0.98)
    assert ramp.sum() >= 4
    assert np.all(np.diff(col[: int(np.argmax(col)) + 1]) >= -1e-6)  # rising from the upper lip
    # smooth: the lens follows curves through the landmarks, not straight polygon edges:
    # the alpha-weighted upper edge has no kink at landmark 62's column
    xs = np.arange(85, 116)
    edge = np.array([np.argmax(alpha[:, x] > 0.5) for x in xs], float)
    second = np.abs(np.diff(edge, 2))
    assert second.max() <= 1.0


def test_mouth_interior_ramp_stays_a_few_pixels_wide_on_a_large_mouth():
    """The soft edge is 0.3 x the widest gap up to ``soft_px`` (4) px, then 4 px, never below 0.12 x
    the gap: on a 1000 px driver's smile (gap ~50 px) 0.3 drew a 15 px dark band between the teeth
    and the lower lip. The puppet's gap here is ~21 px: 0.3 x 21 = 6.3 px -> 4 px; a mouth with
    a gap under 13 px is unchanged."""
    from facetex.puppet._contours import sample_between

    frame, d, p = _mouths()
    s = sample_between(frame, d, p, frame.shape[:2], inset=1.3)  # mouth_interior's default inset
    gmax = float(s.gap.max())
    assert 18 < gmax < 24
    _, wide = mouth_interior(frame, d, p, cavity=None, lip_key=None, soft_px=None)
    _, capped = mouth_interior(frame, d, p, cavity=None, lip_key=None)
    x0, y0, x1, y1 = s.box
    np.testing.assert_allclose(wide[y0:y1, x0:x1], s.edge(0.3), atol=1e-6)
    np.testing.assert_allclose(capped[y0:y1, x0:x1], s.edge(4.0 / gmax), atol=1e-6)  # a 4 px ramp
    # narrower: the middle column's shortfall under the upper lip, sum(1 - alpha), ~(6.2 - 4) / 2 less
    top = slice(0, 90)
    assert (1 - wide[top, 100]).sum() - (1 - capped[top, 100]).sum() > 0.5
    # capped, the inset's margin is the px it is where the cap starts (a 4 / 0.3 px gap: half of it x
    # (1 - 1 / 1.3) = 1.538 px), moving only the ramp's pixels: deeper ones sample the driver 1:1 (the
    # teeth keep their size; scaled by 1.3 they had been 1/1.3 as tall)
    img, alpha = mouth_interior(frame, d, p, cavity=None, lip_key=None, lip_shade=None)
    one = sample_between(frame, d, p, frame.shape[:2])
    edged = sample_between(frame, d, p, frame.shape[:2], edge_margin=(0.5 * 4.0 / 0.3 * (1 - 1 / 1.3), 4.0))
    box_img, box_alpha = img[y0:y1, x0:x1], alpha[y0:y1, x0:x1]
    drawn, deep = box_alpha > 0, (one.depth >= 5) & (box_alpha > 0.99)
    assert deep.sum() > 200
    np.testing.assert_allclose(box_img[drawn], edged.warped[drawn], atol=1e-6)
    np.testing.assert_allclose(box_img[deep], one.warped[deep], atol=1e-6)
    assert np.abs(box_img[deep] - s.warped[deep]).max() > 0.5  # not the inset's scaled interior
    c = p.mean(axis=0)
    small = c + 0.5 * (p - c)  # gap ~10 px: 0.3 x 10 < 4
    np.testing.assert_array_equal(mouth_interior(frame, d, small, cavity=None)[1],
                                  mouth_interior(frame, d, small, cavity=None, soft_px=None)[1])


def test_mouth_interior_keys_out_the_drivers_lip_colour():
    frame, d, p = _mouths()
    lipped = frame.copy()
    inner = np.zeros(frame.shape[:2], np.uint8)
    cv2.fillPoly(inner, [np.round(d).astype(np.int32)], 1)
    lipped[inner > 0] = (0.75, 0.3, 0.3)  # dlib's inner contour on the lips: only lip inside
    _, alpha = mouth_interior(lipped, d, p, cavity=None)
    _, open_alpha = mouth_interior(frame, d, p, cavity=None)
    assert alpha.max() < 0.05 < 0.9 < open_alpha.max()  # no red polygon; the real interior is drawn
    _, off = mouth_interior(lipped, d, p, lip_key=None, cavity=None)
    assert off.max() > 0.9
    # with the cavity (the default) the keyed-out opening is the cavity's shadow: darker than the lips
    img, alpha = mouth_interior(lipped, d, p, lip_shade=None)
    drawn = alpha > 0.9
    assert drawn.sum() > 100
    np.testing.assert_allclose(img[drawn], np.broadcast_to(0.35 * np.float32([0.75, 0.3, 0.3]), img[drawn].shape),
                               atol=0.02)


def test_mouth_interior_keys_each_lip_against_its_own_colour():
    """A dark upper lip and a light, glossy-pink lower lip whose colour reaches 6 px into dlib's
    inner contour: that band is lighter than the two lips' joint median (it was kept as interior,
    a pink band under the teeth), but it is the lower lip's colour: keyed out now; the teeth
    (white) stay."""
    frame, d, p = _mouths()
    yy = np.mgrid[0:frame.shape[0], 0:frame.shape[1]][0]
    outer = np.zeros(frame.shape[:2], np.uint8)
    o = d.copy()
    o[:, 1] = 40 + (d[:, 1] - 40) * 1.8
    o[:, 0] = 60 + (d[:, 0] - 60) * 1.15
    cv2.fillPoly(outer, [np.round(o).astype(np.int32)], 1)
    inner = np.zeros_like(outer)
    cv2.fillPoly(inner, [np.round(d).astype(np.int32)], 1)
    frame[(outer > 0) & (inner == 0) & (yy < 40)] = (0.3, 0.15, 0.17)  # dark upper lip
    frame[(outer > 0) & (inner == 0) & (yy >= 40)] = (0.75, 0.5, 0.55)  # light pink lower lip
    frame[(inner > 0) & (yy >= 48)] = (0.75, 0.5, 0.55)  # its colour inside dlib's contour
    img, alpha = mouth_interior(frame, d, p, cavity=None)  # img: the driver's pixels moved in
    deep = cv2.erode((alpha > 0).astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    pink = (np.abs(img - np.float32([0.75, 0.5, 0.55])).max(axis=-1) < 0.02) & deep
    teeth = (img.min(axis=-1) > 0.85) & deep
    assert pink.sum() > 20 and teeth.sum() > 20
    assert alpha[pink].mean() < 0.2
    assert alpha[teeth].mean() > 0.8


def test_mouth_interior_cavity_starts_at_the_contour_in_the_lips_shade():
    """With ``lip_shade`` the cavity's colour at the puppet's contour is the driver's lips x 0.3 in
    linear light (sRGB (0.75, 0.3, 0.3) -> (0.432, 0.160, 0.160), hand-computed), turning into the
    cavity's shadow (0.35 x the lips when all of the interior is keyed out) where the soft edge's
    ramp ends; darker than the lips everywhere."""
    from facetex.puppet.lighting import linear_to_srgb, srgb_to_linear

    frame, d, p = _mouths()
    lip = np.float32([0.75, 0.3, 0.3])
    lipped = frame.copy()
    inner = np.zeros(frame.shape[:2], np.uint8)
    cv2.fillPoly(inner, [np.round(d).astype(np.int32)], 1)
    lipped[inner > 0] = lip  # all of the interior keyed out: the opening is the cavity's fill only
    img, alpha = mouth_interior(lipped, d, p)
    ramp = mouth_interior(frame, d, p, cavity=None)[1]  # the soft edge's ramp (nothing keyed out there)
    inside = polygon_mask(p, alpha.shape) > 0.5
    shade = linear_to_srgb(srgb_to_linear(lip) * 0.3)
    np.testing.assert_allclose(shade, [0.432, 0.160, 0.160], atol=0.002)
    rim = inside & (ramp < 0.05) & (alpha > 0.9)
    deep = inside & (ramp > 0.99)
    assert rim.sum() > 10 and deep.sum() > 50
    np.testing.assert_allclose(np.median(img[rim], axis=0), shade, atol=0.03)
    np.testing.assert_allclose(np.median(img[deep], axis=0), 0.35 * lip, atol=0.02)
    assert (img[inside & (alpha > 0.5)] <= lip + 1e-4).all()


def test_mouth_interior_keeps_the_teeth_of_a_dim_frame():
    """Teeth only 12 CIELAB units lighter than the lips: at a tenth of the exposure they are 4-5
    units apart; the key measures them at the exposure that brings the lips to L* 40 instead."""
    from facetex.puppet.lighting import _rgb, linear_to_srgb, srgb_to_linear

    frame, d, p = _mouths()
    lips, teeth = _rgb(np.float32([[[46, 30, 20], [58, 28, 20]]]))[0]
    frame[np.all(frame == np.float32([0.75, 0.3, 0.3]), axis=-1)] = lips
    inner = np.zeros(frame.shape[:2], np.uint8)
    cv2.fillPoly(inner, [np.round(d).astype(np.int32)], 1)
    frame[(inner > 0) & (np.mgrid[0:120, 0:160][0] < 35)] = teeth
    # inset 1: the driver's interior between its inner lips fills the puppet's opening, so its teeth
    # land in the opening's top rows (at the default 1.3 they land lower, among the cavity's rows)
    upper = slice(0, 84)  # the upper part of the puppet's opening, where the teeth land
    normal = mouth_interior(frame, d, p, cavity=None, inset=1.0)[1][upper].sum()
    assert normal > 15
    for exposure in (0.25, 0.08):
        dim = linear_to_srgb(srgb_to_linear(frame) * exposure)
        assert mouth_interior(dim, d, p, cavity=None, inset=1.0)[1][upper].sum() > 0.85 * normal


def test_mouth_interior_shades_a_keyed_out_tongue_instead_of_a_flat_slot():
    """The lower half of the driver's opening a tongue of the lips' colour, lighter towards its
    middle (keyed out as lip): with ``cavity_shading`` the puppet's opening there keeps the tongue's
    shading, darker than the lips; without, one flat colour."""
    frame, d, p = _mouths()
    inner = np.zeros(frame.shape[:2], np.uint8)
    cv2.fillPoly(inner, [np.round(d).astype(np.int32)], 1)
    yy, xx = np.mgrid[0:120, 0:160]
    tongue = (inner > 0) & (yy >= 35)  # no black cavity: the darkest interior is the tongue's sides
    light = np.clip(1.0 - np.abs(xx - 60) / 30.0, 0.0, 1.0)[..., None]  # lighter in the middle
    frame[tongue] = (np.float32([0.45, 0.18, 0.18]) + light * np.float32([0.3, 0.12, 0.12]))[tongue]
    shaded, alpha = mouth_interior(frame, d, p, lip_shade=None)
    flat, alpha_flat = mouth_interior(frame, d, p, lip_shade=None, cavity_shading=False)
    np.testing.assert_array_equal(alpha, alpha_flat)  # colour only, not cover
    _, drawn = mouth_interior(frame, d, p, cavity=None)  # the interior itself, the lips keyed out
    deep = (alpha > 0.95) & (drawn < 0.02)  # the opening where only the cavity shows: the tongue
    assert deep.sum() > 20
    lum = np.float32([0.299, 0.587, 0.114])
    assert (shaded[deep] @ lum).std() > 0.005 > 0.001 > (flat[deep] @ lum).std()
    assert (shaded[deep] @ lum).max() < 0.75 * float(np.float32([0.75, 0.3, 0.3]) @ lum)


def test_mouth_interior_cavity_fills_the_whole_opening_under_the_soft_edge():
    frame, d, p = _mouths()
    img, alpha = mouth_interior(frame, d, p, lip_shade=None)  # the cavity's colour alone (shade: above)
    assert np.array_equal(mouth_interior(frame, d, p)[1], alpha)  # the lips' shade changes colour, not cover
    _, inner = mouth_interior(frame, d, p, cavity=None)
    h, w = alpha.shape
    grow = 0.015 * np.linalg.norm(p[4] - p[0])
    inside = polygon_mask(p, (h, w)) > 0.5
    assert alpha[inside].min() > 0.95  # the persona's texture shows nowhere inside its contour
    assert (inner[inside] < 0.5).sum() > 20  # where the interior's soft edge alone would let it through
    edge = inside & (inner < 0.5)
    lum = img[edge] @ np.float32([0.299, 0.587, 0.114])
    # more than half the cavity's dark (the interior's darkest quarter): over a white texture (teeth)
    # the interior alone would be lighter than 0.5 there
    assert lum.max() < 0.5
    # grown a little outside the contour, not more
    near = cv2.dilate(inside.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    assert alpha[near & ~inside].max() > 0.05
    far = cv2.dilate(inside.astype(np.uint8), np.ones((2 * int(grow + 3) + 1,) * 2, np.uint8)) == 0
    assert alpha[far].max() == 0


# ----------------------------------------------------------------------------- the whole composite
def _oval_scene(h=96, w=96):
    """A 96 x 96 frame: blue background, an elliptic face of the driver's skin (0.55, 0.4, 0.3),
    a puppet coverage wider than it, the face's outline and landmarks with only the eye corners set
    (the face's scale). Returns (frame, face, inner face, coverage, driver_oval/driver_points68 kwargs)."""
    yy, xx = np.mgrid[0:h, 0:w]
    frame = np.zeros((h, w, 3), np.float32)
    frame[:] = (0.1, 0.5, 0.8)  # blue background
    face = ((xx - 48) / 26.0) ** 2 + ((yy - 50) / 32.0) ** 2 <= 1
    frame[face] = (0.55, 0.4, 0.3)  # the driver's darker, warmer skin
    inner = ((xx - 48) / 18.0) ** 2 + ((yy - 50) / 24.0) ** 2 <= 1
    coverage = (((xx - 48) / 34.0) ** 2 + ((yy - 50) / 38.0) ** 2 <= 1).astype(np.float32)
    t = np.linspace(0, 2 * np.pi, 36, endpoint=False)
    p68 = np.zeros((68, 2))
    p68[:, 0], p68[:, 1] = 48, 50
    p68[36], p68[45] = (36, 42), (60, 42)  # eye corners: the face's scale
    return frame, face, inner, coverage, {"driver_oval": np.c_[48 + 26 * np.cos(t), 50 + 32 * np.sin(t)],
                                          "driver_points68": p68}


@pytest.mark.parametrize("lighting", ["stats", "sh"])
def test_composite_sits_in_the_frame_and_never_leaves_the_drivers_outline(lighting):
    h, w = 96, 96
    frame, face, inner, coverage, kw = _oval_scene(h, w)
    # a puppet wider than the driver's face, pale grey-pink
    n, _ = _sphere_normals(h, w, 40.0)
    puppet = np.broadcast_to(np.float32([0.85, 0.75, 0.75]), (h, w, 3)).copy()
    out, alpha = composite_face(frame, puppet, coverage, n, params=CompositeParams(lighting=lighting, mouth=False),
                                **kw)
    assert alpha[~face].max() == 0.0  # no halo: nothing outside the driver's face outline
    np.testing.assert_array_equal(out[~face], frame[~face])
    assert alpha[inner].min() > 0.99
    # the pale puppet took the driver's skin colour (it would be ΔE ~ 35 off otherwise)
    de = np.linalg.norm(_lab(out)[inner].mean(axis=0) - _lab(frame)[inner].mean(axis=0))
    assert de < 3.0
    raw = composite_face(frame, puppet, coverage, n, params=CompositeParams(lighting="none", poisson=False,
                                                                           mouth=False), **kw)[0]
    assert np.linalg.norm(_lab(raw)[inner].mean(axis=0) - _lab(frame)[inner].mean(axis=0)) > 20
    # the edge of the composite is no more visible than the driver's own edge at the same place
    edge = alpha > 0.5
    own = boundary_color_step(frame, edge)[0]
    assert boundary_color_step(out, edge)[0] < 1.2 * own


def test_composite_gives_a_smooth_puppet_the_frames_grain_only_inside_the_face():
    """A flat puppet in a frame whose skin has grain (Gaussian noise, sd 0.02): with grain matching
    the composite's skin has most of the frame's pixel-scale detail (Laplacian variance), without
    it (``grain=0``) next to none; outside the driver's outline the frame is untouched either way."""
    frame, face, inner, coverage, kw = _oval_scene()
    rng = np.random.default_rng(1)
    frame[face] += rng.normal(0, 0.02, (int(face.sum()), 1)).astype(np.float32)
    puppet = np.broadcast_to(np.float32([0.6, 0.45, 0.35]), frame.shape).copy()
    grainy = composite_face(frame, puppet, coverage, None, params=CompositeParams(mouth=False), **kw)[0]
    smooth = composite_face(frame, puppet, coverage, None, params=CompositeParams(mouth=False, grain=0.0), **kw)[0]
    own = _lap_var(frame, inner)
    assert _lap_var(smooth, inner) < 0.05 * own
    assert _lap_var(grainy, inner) > 0.5 * own
    np.testing.assert_array_equal(grainy[~face], frame[~face])


def test_composite_gives_a_smooth_puppet_the_frames_texture_a_few_pixels_across_with_grain_reach():
    """The frame's skin has texture ~2 px across (noise blurred by 1 px), which a pixel grain cannot
    give: at half size the composite with ``grain_reach`` (0.06 x the 24 px eye distance: the
    0.7-1.4 px octave) has most of the frame's Laplacian variance, without it little; the frame
    outside the driver's outline stays as it was."""
    frame, face, inner, coverage, kw = _oval_scene()
    rng = np.random.default_rng(2)
    tex = cv2.GaussianBlur(rng.normal(0, 1, frame.shape[:2]).astype(np.float32), (0, 0), 1.0)
    frame[face] += (0.03 * tex / tex.std())[face][:, None]
    puppet = np.broadcast_to(np.float32([0.6, 0.45, 0.35]), frame.shape).copy()
    cp = dict(mouth=False, poisson=False, sharpen=1.0)
    banded = composite_face(frame, puppet, coverage, None, params=CompositeParams(grain_reach=0.06, **cp), **kw)[0]
    pixel = composite_face(frame, puppet, coverage, None, params=CompositeParams(grain_reach=0.0, **cp), **kw)[0]

    def half(x):
        return cv2.resize(x, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)

    small = cv2.resize(inner.astype(np.uint8), None, fx=0.5, fy=0.5, interpolation=cv2.INTER_NEAREST) > 0
    own = _lap_var(half(frame), small)
    assert _lap_var(half(banded), small) > 0.5 * own
    assert _lap_var(half(pixel), small) < 0.6 * _lap_var(half(banded), small)  # 0.38 vs 0.80 of the frame
    np.testing.assert_array_equal(banded[~face], frame[~face])


def test_composite_rejects_an_unknown_lighting():
    with pytest.raises(BadInputError, match="lighting"):
        composite_face(np.zeros((8, 8, 3)), np.zeros((8, 8, 3)), np.ones((8, 8)), np.zeros((8, 8, 3)),
                       driver_oval=np.zeros((3, 2)), driver_points68=np.zeros((68, 2)),
                       params=CompositeParams(lighting="studio"))


def _lap_var(img, mask):
    g = np.ascontiguousarray(np.asarray(img, np.float32) @ np.float32([0.2126, 0.7152, 0.0722]))
    return float(cv2.Laplacian(g, cv2.CV_32F, ksize=1)[mask].var())


def test_match_sharpness_matches_the_references_laplacian_variance_never_blurs_and_is_bounded():
    rng = np.random.default_rng(0)
    n = cv2.GaussianBlur(rng.normal(0, 0.05, (64, 64, 3)).astype(np.float32), (0, 0), 0.7)
    skin = np.ones((64, 64), bool)
    src, ref = 0.5 + 0.5 * n, 0.5 + n
    out, g = match_sharpness(src, ref, skin, skin, max_gain=5.0)
    assert 1.0 < g < 5.0
    assert _lap_var(out, skin) == pytest.approx(_lap_var(ref, skin), rel=0.02)  # the measure matched
    # hand-computed: out = src + (g - 1) (src - mean of its 4 neighbours)
    k4 = np.float32([[0, 0.25, 0], [0.25, 0, 0.25], [0, 0.25, 0]])
    want = np.clip(src + (g - 1) * (src - cv2.filter2D(src, -1, k4, borderType=cv2.BORDER_REFLECT)), 0, 1)
    assert np.abs(out - want).max() < 1e-5
    assert np.abs(out.mean() - src.mean()) < 1e-3  # detail only, the colour stays
    same, g1 = match_sharpness(ref, src, skin, skin)  # a smoother reference: left alone
    assert g1 == 1.0 and np.array_equal(same, ref)
    _, g2 = match_sharpness(src, 0.5 + 10 * n, skin, skin, max_gain=2.0)
    assert g2 == 2.0
    # only the masked pixels set the gain: a reference as smooth as the source there, rough elsewhere
    half = np.zeros((64, 64), bool)
    half[:, :32] = True
    rough = np.where(half[..., None], src, 0.5 + 5 * n)
    inner = half & np.roll(half, -2, axis=1)  # the 3 x 3 Laplacian does not reach the rough side
    _, g3 = match_sharpness(src, rough, inner, inner)
    assert g3 == 1.0
    # a flat puppet disc on an empty outside: the coverage-normalized high-pass does not ring at its edge
    cov = np.zeros((64, 64), np.float32)
    cv2.circle(cov, (32, 32), 20, 1.0, -1)
    flat = np.zeros((64, 64, 3), np.float32) + 0.6 * cov[..., None]
    inside = cov > 0
    strong = 0.5 + 10 * n
    out, g = match_sharpness(flat, strong, inside, skin, coverage=cov, max_gain=2.0)
    assert np.abs(out[inside] - 0.6).max() < 1e-4
    plain, _ = match_sharpness(flat + 0.01 * n, strong, inside, skin, max_gain=2.0)  # its edge rings
    assert np.abs(plain[inside] - 0.6).max() > 0.05


def test_match_sharpness_where_adds_the_detail_only_there():
    """``where``: out = src + (g - 1) x where x high-pass (hand-computed), pixels where it is 0
    unchanged, and the gain still matches the reference's Laplacian variance on the mask."""
    rng = np.random.default_rng(2)
    n = cv2.GaussianBlur(rng.normal(0, 0.05, (64, 64, 3)).astype(np.float32), (0, 0), 0.7)
    src, ref = 0.5 + 0.5 * n, 0.5 + n
    where = np.zeros((64, 64), np.float32)
    where[16:48, 16:48] = 1.0
    where[16:48, 14:16] = 0.5  # a soft edge
    inner = np.zeros((64, 64), bool)
    inner[20:44, 20:44] = True  # the 3 x 3 Laplacian stays inside the full-weight square
    out, g = match_sharpness(src, ref, inner, inner, max_gain=5.0, where=where)
    assert 1.0 < g < 5.0
    assert _lap_var(out, inner) == pytest.approx(_lap_var(ref, inner), rel=0.02)
    k4 = np.float32([[0, 0.25, 0], [0.25, 0, 0.25], [0, 0.25, 0]])
    hp = src - cv2.filter2D(src, -1, k4, borderType=cv2.BORDER_REFLECT)
    want = np.clip(src + (g - 1) * where[..., None] * hp, 0, 1)
    assert np.abs(out - want).max() < 1e-5
    np.testing.assert_array_equal(out[where == 0], src[where == 0])


def test_composite_raises_the_puppets_soft_nose_to_the_drivers_nose():
    """A driver whose nose (iBUG points 29-35) has strong fine detail (the nostrils; noise sd 0.08)
    on grainless skin, a puppet whose nose is soft (sd 0.01, blurred): with ``nose_sharpen`` the
    puppet's nose gains fine detail towards the driver's (bounded: at most 3x its own band), the
    rest of the face is the same as without it."""
    frame, face, inner, coverage, kw = _oval_scene()
    p = kw["driver_points68"].copy()
    p[27:36] = [(48, 30), (48, 36), (48, 42), (48, 50), (42, 56), (45, 57), (48, 58), (51, 57), (54, 56)]
    kw = {**kw, "driver_points68": p, "puppet_points68": p}
    nose = nose_mask(p, frame.shape) & inner
    rng = np.random.default_rng(3)
    frame[nose] += rng.normal(0, 0.08, (int(nose.sum()), 1)).astype(np.float32)
    puppet = np.broadcast_to(np.float32([0.6, 0.45, 0.35]), frame.shape).copy()
    soft = cv2.GaussianBlur(rng.normal(0, 0.01, frame.shape[:2]).astype(np.float32), (0, 0), 0.8)
    puppet += soft[..., None]
    cp = dict(mouth=False, eyes="persona", grain=0.0, poisson=False, occlusion=False)
    on, alpha = composite_face(frame, puppet, coverage, None, params=CompositeParams(**cp), **kw)
    off = composite_face(frame, puppet, coverage, None, params=CompositeParams(nose_sharpen=1.0, **cp), **kw)[0]
    core = cv2.erode(nose.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    assert _lap_var(on, core) > 4 * _lap_var(off, core)
    assert _lap_var(on, core) < _lap_var(frame, core)  # bounded: the driver's nose is far rougher
    far = cv2.dilate(nose.astype(np.uint8), np.ones((15, 15), np.uint8)) == 0
    np.testing.assert_array_equal(on[far], off[far])


def _lab_image(lab):
    from facetex.puppet.lighting import _rgb

    return _rgb(np.asarray(lab, np.float32))


def test_floor_nostrils_hand_case():
    """Driver: skin L* 60, nostrils L* 30 (8 % of its nose: the 3rd percentile is 30); puppet:
    black nostrils (L* 2, a* 0, b* -3) become 30 - 6 log(1 + 28 / 6) = 19.6 L* with a*, b* moved
    0.99 of the way (1 - exp(-28 / 6)) to the driver's nostrils' (12, 10); a pixel at L* 40 (above
    the floor) and everything outside the weight stay as they were."""
    ref_lab = np.zeros((30, 30, 3), np.float32)
    ref_lab[:] = (60, 15, 15)
    ref_lab[12:16, 8:12] = ref_lab[12:16, 18:22] = (30, 12, 10)
    src_lab = np.zeros_like(ref_lab)
    src_lab[:] = (60, 15, 15)
    src_lab[12:16, 8:12] = (2, 0, -3)
    src_lab[12, 18] = (40, 10, 10)
    src_lab[25, 25] = (2, 0, -3)  # dark, outside the nose
    ref, src = _lab_image(ref_lab), _lab_image(src_lab)
    nose = np.zeros((30, 30), bool)
    nose[5:25, 5:25] = True
    out = floor_nostrils(src, ref, nose.astype(np.float32), nose)
    lab = _lab(out)
    np.testing.assert_allclose(lab[12:16, 8:12], np.broadcast_to([19.6, 11.9, 9.9], (4, 4, 3)), atol=0.6)
    unchanged = np.ones((30, 30), bool)
    unchanged[12:16, 8:12] = False
    np.testing.assert_array_equal(out[unchanged], src[unchanged])  # L* 40, the skin, outside the weight
    # a puppet no darker than the driver's nostrils is left alone; so is everything with knee 0
    np.testing.assert_array_equal(floor_nostrils(ref, ref, nose.astype(np.float32), nose), ref)
    np.testing.assert_array_equal(floor_nostrils(src, ref, nose.astype(np.float32), nose, knee=0), src)


def test_composite_lifts_a_puppets_black_nostrils_to_the_drivers_light():
    """A puppet with black nostrils (sRGB 0.02) in a frame whose nostrils are a mid brown: with
    ``nostril_knee`` (default) its nostrils are within 12 L* of the driver's, without it 30 darker;
    far from the nose nothing changes."""
    frame, face, inner, coverage, kw = _oval_scene()
    p = kw["driver_points68"].copy()
    p[27:36] = [(48, 30), (48, 36), (48, 42), (48, 50), (42, 56), (45, 57), (48, 58), (51, 57), (54, 56)]
    kw = {**kw, "driver_points68": p, "puppet_points68": p}
    holes = np.zeros(frame.shape[:2], bool)
    holes[55:58, 42:46] = holes[55:58, 50:54] = True
    frame[holes] = (0.3, 0.18, 0.12)
    puppet = np.broadcast_to(np.float32([0.6, 0.45, 0.35]), frame.shape).copy()
    puppet[holes] = 0.02
    cp = dict(mouth=False, eyes="persona", poisson=False, occlusion=False)
    on = composite_face(frame, puppet, coverage, None, params=CompositeParams(**cp), **kw)[0]
    off = composite_face(frame, puppet, coverage, None, params=CompositeParams(nostril_knee=0, **cp), **kw)[0]
    drv = _lab(frame)[holes][:, 0].mean()
    assert _lab(off)[holes][:, 0].mean() < drv - 20
    assert _lab(on)[holes][:, 0].mean() > drv - 12
    far = cv2.dilate(nose_mask(p, frame.shape).astype(np.uint8), np.ones((15, 15), np.uint8)) == 0
    np.testing.assert_array_equal(on[far], off[far])


def _face68(cx=48.0, cy=40.0, iod=40.0, gap=8.0):
    """iBUG-68-shaped points: outer eye corners 36/45 ``iod`` apart, outer lips 48-59 an ellipse
    around (cx, cy + 10) and inner lips 60-67 ``gap`` px apart in the middle."""
    p = np.zeros((68, 2))
    p[36], p[45] = (cx - iod / 2, cy - 15), (cx + iod / 2, cy - 15)
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    p[48:60] = np.c_[cx - 14 * np.cos(t), cy + 10 - 9 * np.sin(t)]
    ui = np.array([-8, -4, 0, 4, 8], float)
    p[60:65] = np.c_[cx + ui, cy + 10 - gap / 2 * np.array([0, 1, 1, 1, 0])]
    p[65:68] = np.c_[cx + ui[3:0:-1], np.full(3, cy + 10 + gap / 2)]
    return p


def _fuller(p, k=1.35):
    """``p`` with its outer lips scaled by ``k`` about the mouth's centre (fuller lips)."""
    q = p.copy()
    c = p[48:60].mean(axis=0)
    q[48:60] = c + k * (p[48:60] - c)
    return q


def test_lip_regions_put_the_lips_colour_where_the_puppets_lips_are():
    """A fuller-lipped persona (outer lips 1.35x the driver's) lighter-lipped than her skin on a
    pale driver: with the regions at the driver's lips her lip edge outside them takes the skin's
    mapping and turns white (the rim); with :func:`lip_regions` all of her lips are the driver's
    lip colour (hand-computed as in the test above), measured on each face's own lips."""
    h, w = 80, 96
    d = _face68(gap=4.0)
    pp = _fuller(d, 1.5)
    p_outer = polygon_mask(pp[48:60], (h, w)) > 0.5
    d_outer = polygon_mask(d[48:60], (h, w)) > 0.5
    src_lab = np.where(p_outer[..., None], np.float32([60.0, 30.0, 15.0]), np.float32([45.0, 14.0, 20.0]))
    ref_lab = np.where(d_outer[..., None], np.float32([55.0, 35.0, 12.0]), np.float32([75.0, 10.0, 16.0]))
    src, ref = _rgb(src_lab.astype(np.float32)), _rgb(ref_lab.astype(np.float32))
    skin = ~cv2.dilate(p_outer.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    rim = p_outer & ~cv2.dilate(d_outer.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert rim.sum() > 30
    old = _lab(transfer_skin_colour(src, ref, skin, skin, sigma=np.inf, **lip_regions(d, None, (h, w))))
    assert np.median(old[rim][:, 0]) > 85.0  # the rim: white
    regions = lip_regions(d, pp, (h, w))
    wl, ref_ring, src_ring = regions["lips"]
    assert (src_ring & ~d_outer).sum() > 30 and not (ref_ring & ~d_outer).any()  # each face's own lips
    new = _lab(transfer_skin_colour(src, ref, skin, skin, sigma=np.inf, **regions))
    core = rim & (wl > 0.999)
    np.testing.assert_allclose(new[core], np.broadcast_to([55.0, 35.0, 12.0], new[core].shape), atol=0.4)
    np.testing.assert_allclose(new[skin], np.broadcast_to([75.0, 10.0, 16.0], new[skin].shape), atol=0.4)


def test_lip_ceiling_caps_the_lips_lightness_at_the_drivers_lip_median():
    """Teeth (L 90) on the persona's lips (L 50) with the driver's lips at L 55: the lip detail
    would make them 55 + 1.2 x 40 = 100; the ceiling holds them at 55 + 6 = 61 (and only them)."""
    h, w = 80, 96
    p = _face68(gap=4.0)
    outer = polygon_mask(p[48:60], (h, w)) > 0.5
    wl, ring = lip_weights(p, (h, w))
    yy, xx = np.mgrid[0:h, 0:w]
    teeth = ring & (wl > 0.999) & (yy < p[62, 1]) & (np.abs(xx - p[62, 0]) < 5)  # on the upper lip
    assert teeth.sum() >= 4
    src_lab = np.where(outer[..., None], np.float32([50.0, 30.0, 15.0]), np.float32([45.0, 14.0, 20.0]))
    src_lab[teeth] = (90.0, 0.0, 5.0)
    ref_lab = np.where(outer[..., None], np.float32([55.0, 35.0, 12.0]), np.float32([75.0, 10.0, 16.0]))
    src, ref = _rgb(src_lab.astype(np.float32)), _rgb(ref_lab.astype(np.float32))
    skin = ~cv2.dilate(outer.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    free = _lab(transfer_skin_colour(src, ref, skin, skin, sigma=np.inf, lips=(wl, ring)))
    capped = _lab(transfer_skin_colour(src, ref, skin, skin, sigma=np.inf, lips=(wl, ring), lip_ceiling=6.0))
    assert free[teeth][:, 0].min() > 90.0
    np.testing.assert_allclose(capped[teeth][:, 0], 61.0, atol=0.6)
    lips = ring & (wl > 0.999) & ~cv2.dilate(teeth.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    np.testing.assert_allclose(capped[lips], free[lips], atol=0.05)  # the lips below the ceiling: as they were


def test_lip_ceiling_scales_the_lips_highlights_instead_of_flattening_them():
    """A persona's lips with L from 40 to 70 (a lower lip much lighter than the upper), the driver's
    lips uniform at L 55, skins at L 50 and 60 (gain 1.2), ceiling 6: below the lips' median (55)
    the detail keeps the gain 1.2; above it the gain is 6 / (90th percentile - median), so the
    lightening lower lip stays a ramp up to the ceiling instead of a flat patch (hand-computed)."""
    h, w = 40, 64
    ring = np.zeros((h, w), bool)
    ring[8:32, 2:62] = True
    wl = ring.astype(np.float32)
    L = np.broadcast_to(np.linspace(40.0, 70.0, 60, dtype=np.float32), (24, 60))
    src_lab = np.broadcast_to(np.float32([50.0, 14.0, 20.0]), (h, w, 3)).copy()
    src_lab[8:32, 2:62] = np.stack([L, np.full_like(L, 30.0), np.full_like(L, 15.0)], axis=-1)
    ref_lab = np.broadcast_to(np.float32([60.0, 10.0, 16.0]), (h, w, 3)).copy()
    ref_lab[ring] = (55.0, 35.0, 12.0)
    src, ref = _rgb(src_lab), _rgb(ref_lab)
    skin = ~cv2.dilate(ring.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    out = _lab(transfer_skin_colour(src, ref, skin, skin, sigma=np.inf, lips=(wl, ring), lip_ceiling=6.0))
    got_src = _lab(src)[ring][:, 0]  # the source lightness after the 8-bit-free sRGB round trip
    med = np.median(got_src)
    g_hi = 6.0 / (np.percentile(got_src, 90) - med)
    assert 0.4 < g_hi < 0.6
    expect = np.where(got_src > med, 55.0 + g_hi * (got_src - med), 55.0 + 1.2 * (got_src - med))
    expect = np.minimum(expect, 61.0)
    np.testing.assert_allclose(out[ring][:, 0], expect, atol=0.3)
    lower = got_src > med + 1.0
    assert np.ptp(out[ring][lower & (got_src < np.percentile(got_src, 88)), 0]) > 4.0  # a ramp, not flat


def test_lips_take_the_drivers_lip_colour_not_the_skins():
    """A persona whose lips are lighter than her skin (L 45 skin, L 60 lips) on a pale driver whose
    lips are darker than his (L 75 skin, L 55 lips): with the lip weights the lips come out at the
    driver's lip median plus the persona's lip detail (hand-computed, gain 75 / 45 clipped to 1.2),
    the skin as before; without them the lips are the driver's skin plus 1.2 x 15: white."""
    h, w = 80, 96
    p = _face68(gap=4.0)
    wl, ring = lip_weights(p, (h, w))
    assert wl.max() == pytest.approx(1.0, abs=1e-3) and wl[5, 5] == 0.0
    assert ring.sum() > 50 and not ring[int(p[62, 1]) + 2, int(p[62, 0])]  # the ring excludes the interior
    outer = polygon_mask(p[48:60], (h, w)) > 0.5
    src_lab = np.where(outer[..., None], np.float32([60.0, 30.0, 15.0]), np.float32([45.0, 14.0, 20.0]))
    ref_lab = np.where(outer[..., None], np.float32([55.0, 35.0, 12.0]), np.float32([75.0, 10.0, 16.0]))
    src, ref = _rgb(src_lab.astype(np.float32)), _rgb(ref_lab.astype(np.float32))
    skin = ~cv2.dilate(outer.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    out = _lab(transfer_skin_colour(src, ref, skin, skin, sigma=np.inf, lips=(wl, ring)))
    core = ring & (wl > 0.999)  # the weight is feathered at the lips' outline
    assert core.sum() > 30
    np.testing.assert_allclose(out[core], np.broadcast_to([55.0, 35.0, 12.0], out[core].shape), atol=0.4)
    np.testing.assert_allclose(out[skin], np.broadcast_to([75.0, 10.0, 16.0], out[skin].shape), atol=0.4)
    white = _lab(transfer_skin_colour(src, ref, skin, skin, sigma=np.inf))
    assert np.median(white[ring][:, 0]) > 85.0  # 75 + 1.2 x 15 = 93, clipped to the sRGB gamut


def test_open_lips_take_each_of_the_drivers_lips_colours():
    """An open mouth whose driver has a dark upper lip (L 50) and a light lower lip (L 65), on a
    persona whose lips are one colour (L 60): with the open-lip weights each lip's core comes out
    at the driver's own lip's colour (hand-computed: r' + (src - s') with src flat = r'); with one
    lip region both lips get the same colour. Closed lips have no parts; a half-open
    mouth's parts weigh 1 - closure."""
    h, w = 240, 288
    p = 3 * _face68(gap=10.0)  # 10 / 16 of the mouth width: wide open; x 3: lips thicker than the feather
    parts = open_lip_weights(p, (h, w))
    assert len(parts) == 2
    up_poly = np.r_[p[48:55], p[[64, 63, 62, 61, 60]]]
    lo_poly = np.r_[p[54:60], p[[48, 60, 67, 66, 65, 64]]]
    upper, lower = (polygon_mask(q, (h, w)) > 0.5 for q in (up_poly, lo_poly))
    assert parts[0][1].sum() > 20 and not (parts[0][1] & lower).any()
    assert parts[1][1].sum() > 20 and not (parts[1][1] & upper).any()
    assert open_lip_weights(_face68(gap=0.0), (h, w)) == []
    half = open_lip_weights(3 * _face68(gap=0.06 * 16), (h, w))
    c = mouth_closure(_face68(gap=0.06 * 16)[60:68])
    assert 0 < c < 1 and half[0][0].max() == pytest.approx(1 - c, abs=0.02)

    outer = polygon_mask(p[48:60], (h, w)) > 0.5
    inner = polygon_mask(p[60:68], (h, w)) > 0.5
    ref_lab = np.where(upper[..., None], np.float32([50.0, 35.0, 12.0]),
                       np.where(lower[..., None], np.float32([65.0, 30.0, 14.0]), np.float32([75.0, 10.0, 16.0])))
    ref_lab = np.where(inner[..., None], np.float32([20.0, 5.0, 5.0]), ref_lab)
    src_lab = np.where(outer[..., None] & ~inner[..., None], np.float32([60.0, 30.0, 15.0]),
                       np.float32([45.0, 14.0, 20.0]))
    src, ref = _rgb(src_lab.astype(np.float32)), _rgb(ref_lab.astype(np.float32))
    skin = ~cv2.dilate(outer.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    lips = lip_weights(p, (h, w))
    out = _lab(transfer_skin_colour(src, ref, skin, skin, sigma=np.inf, lips=lips, lip_parts=parts))
    for (wt, ring), want in zip(parts, ([50.0, 35.0, 12.0], [65.0, 30.0, 14.0])):
        core = ring & (wt > 0.999)
        assert core.sum() > 10
        np.testing.assert_allclose(out[core], np.broadcast_to(want, out[core].shape), atol=0.5)
    one = _lab(transfer_skin_colour(src, ref, skin, skin, sigma=np.inf, lips=lips))
    cores = [ring & (wt > 0.999) for wt, ring in parts]
    gap_one = abs(np.median(one[cores[0]][:, 0]) - np.median(one[cores[1]][:, 0]))
    assert gap_one < 3.0  # one median: both lips alike, not the driver's 15 apart


def test_mouth_closure_follows_the_lip_gap():
    assert mouth_closure(_face68(gap=0.0)[60:68]) == 1.0
    assert mouth_closure(_face68(gap=0.04 * 16)[60:68]) == pytest.approx(1.0)  # at `closed` x width 16
    assert mouth_closure(_face68(gap=0.08 * 16)[60:68]) == pytest.approx(0.0)
    assert 0.0 < mouth_closure(_face68(gap=0.06 * 16)[60:68]) < 1.0
    assert mouth_closure(np.full((8, 2), np.nan)) == 0.0


def test_fill_mouth_interior_replaces_the_teeth_by_the_lips_as_the_mouth_closes():
    h, w = 80, 96
    p = _face68(gap=10.0)
    tex = np.zeros((h, w, 3), np.float32) + np.float32([0.55, 0.35, 0.3])  # lips/skin all round
    inner = polygon_mask(p[60:68], (h, w)) > 0.5
    tex[inner] = (0.95, 0.95, 0.9)  # teeth
    open_ = fill_mouth_interior(tex, p[60:68], 0.0)
    assert np.array_equal(open_, tex)
    shut = fill_mouth_interior(tex, p[60:68], 1.0)
    assert np.abs(shut[inner] - [0.55, 0.35, 0.3]).max() < 0.03  # no white left between the lips
    far = ~cv2.dilate(inner.astype(np.uint8), np.ones((13, 13), np.uint8)).astype(bool)
    assert np.array_equal(shut[far], tex[far])  # nothing else changes
    half = fill_mouth_interior(tex, p[60:68], 0.5)
    c = (int(round(p[62, 1])) + 3, int(round(p[62, 0])))
    np.testing.assert_allclose(half[c], 0.5 * (tex[c] + shut[c]), atol=0.01)


def test_fill_mouth_interior_ramps_from_the_upper_lip_to_the_lower_down_each_column():
    """Upper lip dark (0.3), lower lip pink (0.7) round a 10 px open mouth: every column of the
    filled hole is a straight ramp between its top and bottom pixels, so a closing mesh that
    samples it at drifting sub-pixel heights gets a smoothly drifting colour (inpainted, it was dark
    above a hard seam and pink below: the closed lip line in stair steps of dark and pink runs)."""
    h, w = 80, 96
    p = _face68(gap=10.0)
    yy = np.mgrid[0:h, 0:w][0]
    mid = 0.5 * (p[62, 1] + p[66, 1])
    tex = np.where((yy < mid)[..., None], np.float32(0.3), np.float32(0.7)) * np.ones(3, np.float32)
    inner = polygon_mask(p[60:68], (h, w)) > 0.5
    tex[inner] = 0.95  # teeth
    shut = fill_mouth_interior(tex, p[60:68], 1.0)[..., 0]
    checked = 0
    for x in range(int(p[60, 0]), int(p[64, 0]) + 1):
        ys = np.flatnonzero(inner[:, x])
        if ys.size < 5:  # the corners' short columns
            continue
        col = shut[ys, x]
        top, bottom = col[0], col[-1]
        assert top < 0.45 and bottom > 0.55  # each end takes its own lip
        expected = top + (bottom - top) * (ys - ys[0]) / (ys[-1] - ys[0])  # hand-computed ramp
        np.testing.assert_allclose(col, expected, atol=0.02)
        checked += 1
    assert checked >= 8


def test_eyeballs_keep_the_personas_colour_the_lids_take_the_drivers():
    """A dark persona's brown iris on a pale driver: with ``keep`` = the eye weights the eyeball is
    the persona's own colour (Lab unchanged), the skin the driver's."""
    from facetex.puppet.composite import eye_weights

    h, w = 80, 96
    p = _face68()
    p[36:42] = [(20, 30), (26, 26), (32, 26), (38, 30), (32, 34), (26, 34)]
    p[42:48] = [(58, 30), (64, 26), (70, 26), (76, 30), (70, 34), (64, 34)]
    ew = eye_weights(p, (h, w))
    eyes = np.maximum(polygon_mask(p[36:42], (h, w)), polygon_mask(p[42:48], (h, w))) > 0.5
    assert ew.max() > 0.95 and ew[~eyes].max() == 0.0  # nothing outside the lids' edges
    src_lab = np.where(eyes[..., None], np.float32([25.0, 8.0, 14.0]), np.float32([40.0, 14.0, 20.0]))
    ref_lab = np.broadcast_to(np.float32([75.0, 10.0, 16.0]), src_lab.shape)
    src, ref = _rgb(src_lab.astype(np.float32)), _rgb(np.ascontiguousarray(ref_lab))
    out = _lab(transfer_skin_colour(src, ref, ~eyes, ~eyes, sigma=np.inf, keep=ew))
    core = ew > 0.99
    assert core.sum() >= 6
    np.testing.assert_allclose(out[core], np.broadcast_to([25.0, 8.0, 14.0], out[core].shape), atol=0.3)
    grey = _lab(transfer_skin_colour(src, ref, ~eyes, ~eyes, sigma=np.inf))
    assert np.median(grey[core][:, 0]) > 50  # without it: 75 + 1.2 x (25 - 40) = 57, a grey iris


def test_eye_weights_inset_starts_the_feather_inside_the_lids():
    """Eyes 40 x 20 px, eye-corner distance 100 px: inset 0.03 (3 px) makes the weights 0 on the
    lids' edges (the plain inward feather is ~0.5 there) and leaves the eyeballs' middle at 1."""
    from facetex.geometry.masks import polygon_mask
    from facetex.puppet.composite import eye_weights

    h, w = 80, 140
    p = _face68(cx=70.0, cy=50.0)
    p[36:42] = [(20, 30), (33, 20), (47, 20), (60, 30), (47, 40), (33, 40)]
    p[42:48] = [(80, 30), (93, 20), (107, 20), (120, 30), (107, 40), (93, 40)]
    eyes = np.maximum(polygon_mask(p[36:42], (h, w)), polygon_mask(p[42:48], (h, w))) > 0.5
    edge = eyes & ~(cv2.erode(eyes.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    plain, ins = eye_weights(p, (h, w)), eye_weights(p, (h, w), inset=0.03)
    assert np.median(plain[edge]) > 0.3 and ins[edge].max() < 0.05
    assert ins[30, 40] > 0.99 and plain[30, 40] > 0.99 and ins[~eyes].max() == 0.0


def test_grown_eye_weights_reach_past_the_lids_edges_and_keep_lightness_only():
    """grow 0.1 x the eye distance (56 px: 6 px) keeps the eyeballs' weight at 1 on the lids'
    edges and ends 6 px beyond them; with keep_chroma False the kept eyeball keeps its lightness (25)
    and takes the transfer's chroma: the driver's skin (10, 16) + the eyeball's offset from the
    persona's skin (8 - 14, 14 - 20), hand-computed (4, 10)."""
    from facetex.puppet.composite import eye_weights

    h, w = 80, 96
    p = _face68()
    p[36:42] = [(20, 30), (26, 26), (32, 26), (38, 30), (32, 34), (26, 34)]
    p[42:48] = [(58, 30), (64, 26), (70, 26), (76, 30), (70, 34), (64, 34)]
    eyes = np.maximum(polygon_mask(p[36:42], (h, w)), polygon_mask(p[42:48], (h, w))) > 0.5
    ew = eye_weights(p, (h, w), grow=0.1)
    edge = eyes & ~(cv2.erode(eyes.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    assert ew[edge].min() > 0.9 and eye_weights(p, (h, w))[edge].max() < 0.6  # the plain feather pales the edge
    ring = cv2.dilate(eyes.astype(np.uint8), np.ones((13, 13), np.uint8)) > 0
    far = ~cv2.dilate(eyes.astype(np.uint8), np.ones((15, 15), np.uint8)).astype(bool)
    assert ew[ring & ~eyes].max() > 0.5 and ew[far].max() == 0.0
    # spread 0.02 x 56 px (sigma 1.1 px) both ways: no cut where the grown weight ends on skin
    soft = eye_weights(p, (h, w), grow=0.1, spread=0.02)
    grown = ew > 0
    rim = cv2.dilate(grown.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~grown
    assert ew[rim].max() == 0.0 and 0.01 < soft[rim].min() and soft[rim].max() < 0.6
    assert soft[far & ~cv2.dilate(grown.astype(np.uint8), np.ones((11, 11), np.uint8)).astype(bool)].max() < 1e-3
    assert soft.sum() == pytest.approx(ew.sum(), rel=0.02)  # a blur, not a growth
    src_lab = np.where(eyes[..., None], np.float32([25.0, 8.0, 14.0]), np.float32([40.0, 14.0, 20.0]))
    ref_lab = np.broadcast_to(np.float32([75.0, 10.0, 16.0]), src_lab.shape)
    src, ref = _rgb(src_lab.astype(np.float32)), _rgb(np.ascontiguousarray(ref_lab))
    plain = eye_weights(p, (h, w))
    out = _lab(transfer_skin_colour(src, ref, ~ring, ~ring, sigma=np.inf, keep=plain, keep_chroma=False))
    core = plain > 0.99
    np.testing.assert_allclose(out[core], np.broadcast_to([25.0, 4.0, 10.0], out[core].shape), atol=0.4)


def test_lids_take_the_drivers_lid_lightness():
    """A dark persona whose lids are much darker than her skin (L 25 lids, L 45 skin) on a pale
    driver with lids barely darker than his skin (L 68 lids, L 75 skin): with the lid weights the
    ring round the eyes comes out at the driver's lid median (hand-computed: no detail inside the
    lids); with the skin's field alone at 75 + 1.2 x (25 - 45) = 51: a dark ring."""
    from facetex.puppet.composite import lid_weights

    h, w = 80, 96
    p = _face68(gap=4.0)
    t = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    for k, cx in ((36, 30.0), (42, 66.0)):  # two eyes 36 px apart, 12 x 6 px
        p[k:k + 6] = np.c_[cx + 6 * np.cos(t), 25 + 3 * np.sin(t)]
    p[0], p[16] = (8.0, 30.0), (88.0, 30.0)  # a face 80 px wide: lids grown by 0.045 x 80 = 3.6 px
    wl, ring = lid_weights(p, (h, w))
    balls = np.maximum(polygon_mask(p[36:42], (h, w)), polygon_mask(p[42:48], (h, w))) > 0.5
    assert ring.sum() > 20 and not (ring & balls).any()
    lidzone = (wl > 0.5) & ~balls
    src_lab = np.where(lidzone[..., None], np.float32([25.0, 12.0, 14.0]), np.float32([45.0, 14.0, 20.0]))
    ref_lab = np.where(lidzone[..., None], np.float32([68.0, 11.0, 15.0]), np.float32([75.0, 10.0, 16.0]))
    src, ref = _rgb(src_lab.astype(np.float32)), _rgb(ref_lab.astype(np.float32))
    skin = ~cv2.dilate((wl > 0).astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    out = _lab(transfer_skin_colour(src, ref, skin, skin, sigma=np.inf, lids=(wl, ring)))
    core = ring & (wl > 0.999)
    assert core.sum() > 10
    np.testing.assert_allclose(np.median(out[core][:, 0]), 68.0, atol=0.5)
    ringed = _lab(transfer_skin_colour(src, ref, skin, skin, sigma=np.inf))
    assert np.median(ringed[core][:, 0]) == pytest.approx(75 + 1.2 * (25 - 45), abs=1.0)


def _band_scene(driver_l: float, puppet_dark: float, gap: float = 8.0, driver_band: float | None = None):
    """A mouth twice _face68's size (inner width 32 px) open by 2 x ``gap``: the driver's lips
    CIELAB (driver_l, 35, 15) round a dark interior (their 2 px next to it at L* ``driver_band``
    if given); the puppet's lips (50, 20, 10) but for the 2 px next to its inner contour,
    (puppet_dark, 0, 0) (a texture's dark inner-lip gap)."""
    h, w = 160, 192
    p = _face68(gap=gap)
    c = p[48:60].mean(axis=0)
    p = (p - c) * 2.0 + [w / 2, h / 2]
    inner = polygon_mask(p[60:68], (h, w)) > 0.5
    outer = polygon_mask(p[48:60], (h, w)) > 0.5
    d = cv2.distanceTransform((~inner).astype(np.uint8), cv2.DIST_L2, 3)
    skin = np.float32([60.0, 15.0, 20.0])
    frame = np.where(outer[..., None], np.float32([driver_l, 35.0, 15.0]), skin)
    frame[inner] = (12.0, 5.0, 5.0)
    puppet = np.where(outer[..., None], np.float32([50.0, 20.0, 10.0]), skin)
    dark = outer & ~inner & (d <= 2.0)
    if driver_band is not None:
        frame[dark] = (driver_band, 35.0, 15.0)
    puppet[dark] = (puppet_dark, 0.0, 0.0)
    puppet[inner] = (12.0, 5.0, 5.0)
    return p, _rgb(frame.astype(np.float32)), _rgb(puppet.astype(np.float32)), dark, inner, outer, d


def test_lift_inner_lips_raises_an_open_mouths_dark_inner_band_to_the_drivers():
    """The 3.2 px band is 2 rows dark, 1 row lip: puppet band percentiles 10, 50, 90 are
    (10, 10, 50), the driver's 10 and 50 both 50: the dark pixels are lifted by 50 - 10 = 40 L*
    (hand-computed) and, lifted by more than 20, take the driver's band chroma (35, 15); the lip
    pixels at the puppet's 90th percentile are not lifted; the opening's first pixel inside the
    contour is lifted too, and nothing else changes."""
    p, frame, puppet, dark, inner, outer, d = _band_scene(50.0, 10.0)
    out = lift_inner_lips(puppet, frame, p, p)
    lab = _lab(out)
    core = dark & (d >= 0.9) & (d <= 1.6)  # in full to half the band's width
    assert core.sum() > 20
    np.testing.assert_allclose(np.median(lab[core], axis=0), [50.0, 35.0, 15.0], atol=2.5)
    # then tapering: at 2 px, 1.5 - 2 / 3.2 = 0.875 of the 40 L* lift (hand-computed; blurred by 0.7 px)
    taper = dark & (d > 1.9)
    assert taper.sum() > 10
    assert 10.0 + 0.8 * 40.0 < np.median(lab[taper][:, 0]) < 10.0 + 0.95 * 40.0
    assert _lab(puppet)[core][:, 0].max() < 12  # it was dark
    d_in = cv2.distanceTransform(inner.astype(np.uint8), cv2.DIST_L2, 3)
    rim = inner & (d_in <= 1.0)  # the opening's edge the contour cuts: lifted with the band
    assert np.median(lab[rim][:, 0]) > 45.0 and _lab(puppet)[rim][:, 0].max() < 13
    far = ~(outer & ~inner & (d <= 4.5)) & ~(inner & (d_in <= 2.5))
    assert np.array_equal(out[far], puppet[far])  # only the band and that edge change
    body = outer & ~inner & (d > 2.6) & (d <= 3.2)  # the band's lip pixels at the quantile top: no lift
    assert np.abs(lab[body] - _lab(puppet)[body]).max() < 1.0


def test_lift_inner_lips_never_darkens_and_leaves_closed_mouths_alone():
    p, frame, puppet, *_ = _band_scene(50.0, 40.0, driver_band=20.0)  # the driver's band darker
    assert np.array_equal(lift_inner_lips(puppet, frame, p, p), puppet)
    p, frame, puppet, *_ = _band_scene(50.0, 10.0, gap=0.0)  # closed lips: the dark line is theirs
    assert np.array_equal(lift_inner_lips(puppet, frame, p, p), puppet)
    assert np.array_equal(lift_inner_lips(puppet, frame, np.full((68, 2), np.nan), p), puppet)


def test_composite_face_lifts_the_inner_lips_only_with_a_lip_band(monkeypatch):
    """composite_face hands the puppet, the frame and both faces' landmarks (box px) to
    lift_inner_lips with CompositeParams.lip_band (relative to each face's lips with the persona's
    colour), and skips it at 0."""
    import importlib

    comp = importlib.import_module("facetex.puppet.composite")
    calls = []

    def spy(image, frame, d68, p68, *, band, relative):
        calls.append((np.asarray(image).shape, np.asarray(frame).shape, np.asarray(d68).copy(), band, relative))
        return image

    monkeypatch.setattr(comp, "lift_inner_lips", spy)
    h, w = 96, 96
    frame, face, inner, coverage, kw = _oval_scene(h, w)
    n, _ = _sphere_normals(h, w, 40.0)
    puppet = np.broadcast_to(np.float32([0.85, 0.75, 0.75]), (h, w, 3)).copy()
    p68 = _face68(cx=48.0, cy=52.0, iod=24.0)
    kw["driver_points68"] = p68
    composite_face(frame, puppet, coverage, n, puppet_points68=p68, **kw)
    assert len(calls) == 1
    img_shape, fr_shape, d68, band, relative = calls[0]
    assert band == CompositeParams().lip_band == 0.2 and img_shape == fr_shape and not relative
    assert np.allclose(p68 - d68, p68[0] - d68[0])  # the same points, shifted into the face's box
    calls.clear()
    composite_face(frame, puppet, coverage, n, puppet_points68=p68, params=CompositeParams(colour="persona"), **kw)
    assert calls[0][4]  # the persona keeps its lip colour: its band is lifted relative to its lips
    calls.clear()
    composite_face(frame, puppet, coverage, n, puppet_points68=p68, params=CompositeParams(lip_band=0.0), **kw)
    assert calls == []


def test_lift_inner_lips_relative_takes_the_drivers_band_relative_to_each_faces_lips():
    """The driver's lips are L* 70 all over, the puppet's 50 with a dark (10) band (a persona that
    keeps its own lip colour): relative, the band is lifted to the puppet's lips, 50 (the driver's
    band 70 moved by the lips' difference 50 - 70), with their chroma; not to 70, a light rim."""
    p, frame, puppet, dark, inner, outer, d = _band_scene(70.0, 10.0)
    core = dark & (d >= 0.9) & (d <= 1.6)  # lifted in full (to half the band's width)
    assert np.median(_lab(lift_inner_lips(puppet, frame, p, p))[core][:, 0]) > 65.0  # absolute: the rim
    lab = _lab(lift_inner_lips(puppet, frame, p, p, relative=True))
    assert abs(np.median(lab[core][:, 0]) - 50.0) < 2.5
    np.testing.assert_allclose(np.median(lab[core][:, 1:], axis=0), [20.0, 10.0], atol=2.5)  # the puppet's lips' chroma


def _two_band_skin(skin_l: float, left_l: float, right_l: float) -> tuple[np.ndarray, np.ndarray]:
    """(bool (40, 80) two bands, sRGB skin of L* ``skin_l`` with the left band at ``left_l`` and the
    right at ``right_l``; a*, b* 12, 18)."""
    band = np.zeros((40, 80), bool)
    band[15:25, 10:30] = band[15:25, 50:70] = True
    lab = np.broadcast_to(np.float32([skin_l, 12.0, 18.0]), (40, 80, 3)).copy()
    lab[15:25, 10:30, 0] = left_l
    lab[15:25, 50:70, 0] = right_l
    return band, _rgb(lab)


def _flat_skin(lightness: float, shape) -> np.ndarray:
    """A driver's flat skin (L* ``lightness``, a*, b* 14, 22) in sRGB."""
    return _rgb(np.ascontiguousarray(np.broadcast_to(np.float32([lightness, 14.0, 22.0]), tuple(shape) + (3,))))


@pytest.mark.parametrize("driver_l", [35.0, 80.0])
def test_keep_dark_keeps_only_the_darker_lightness(driver_l):
    """A persona (skin L 70) with a dark rim (L 30) round one eye and a pale one (L 90) round the
    other, on a dark (L 35) or a pale (L 80) driver: where ``keep_dark`` is 1 the lightness is the
    smaller of the persona's and the plain transfer's, its a*, b* the transfer's; where it is 0 the
    plain transfer, unchanged. On the pale driver the dark rim stays darker than the transfer makes
    it; on the dark one the pale rim takes the transfer (it is not kept pale)."""
    band, src = _two_band_skin(70.0, 30.0, 90.0)
    ref = _flat_skin(driver_l, band.shape)
    plain = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf))
    out = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf, keep_dark=band.astype(np.float32)))
    a = _lab(src)
    np.testing.assert_allclose(out[~band], plain[~band], atol=1e-3)
    # (the sRGB round trip of a light, saturated Lab colour moves L* by up to ~0.5)
    np.testing.assert_allclose(out[band][:, 0], np.minimum(a[band][:, 0], plain[band][:, 0]), atol=0.8)
    dark = band.copy()
    dark[:, 40:] = False  # (the pale rim's plain transfer on the pale driver is out of gamut: its chroma clipped)
    np.testing.assert_allclose(out[dark][:, 1:], plain[dark][:, 1:], atol=0.8)
    if driver_l > 70:
        assert out[18, 15, 0] < plain[18, 15, 0] - 1.0  # the dark rim kept dark
    else:
        assert out[18, 55, 0] == pytest.approx(plain[18, 55, 0], abs=0.3)  # the pale rim not kept pale
        assert out[18, 55, 0] < a[18, 55, 0] - 10


def test_keep_dark_on_a_darker_persona_takes_the_skins_ratio():
    """A dark persona (skin L 40) with a dark lid rim (L 20) and a lighter patch (L 50) where
    ``keep_dark`` is 1, on a pale driver (L 75): the skins' ratio 75 / 40 = 1.875 is above the
    lightness gain's bound 1.2, so the rim's darker-than-skin detail takes it (75 - 1.875 x 20 =
    37.5; kept as it was it would be L 20, a dark almond round a pale driver's eye; the plain
    transfer 75 - 1.2 x 20 = 51), the lighter patch stays the plain transfer's (75 + 1.2 x 10 = 87);
    with ``brow_gain`` 1.5 the rim takes 75 - 1.5 x 20 = 45."""
    band, src = _two_band_skin(40.0, 20.0, 50.0)
    ref = _flat_skin(75.0, band.shape)
    plain = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf))
    for brow_gain, rim in ((2.0, 37.5), (1.5, 45.0)):
        out = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf, keep_dark=band.astype(np.float32),
                                        brow_gain=brow_gain))
        np.testing.assert_allclose(out[~band], plain[~band], atol=1e-3)
        assert np.median(out[15:25, 10:30, 0]) == pytest.approx(rim, abs=0.8)
        assert np.median(plain[15:25, 10:30, 0]) == pytest.approx(51.0, abs=0.8)
        np.testing.assert_allclose(out[15:25, 50:70], plain[15:25, 50:70], atol=1e-3)


def test_chroma_gain_and_highlight_knee_by_hand():
    """A saturated persona skin (L 50, a* 20, b* 30: chroma 36.1) with a dark, less saturated band
    (L 30, a* 10, b* 15) and a highlight band (L 65, same a*, b* as the skin) on a driver of the same
    lightness but chroma 14.4 (a* 8, b* 12): the chroma ratio 0.4 is clipped to ``chroma_gain``'s
    0.5, so the dark band's a*, b* are (8, 12) + 0.5 x (-10, -15) = (3, 4.5), not (-2, -3) (blue,
    the default gain 1); the highlight's +15 L* becomes 6 tanh(15 / 6) = +5.92 with
    ``highlight_knee`` 6, the dark band's lightness (30: gain 1) unchanged."""
    band = np.zeros((40, 80), bool)
    band[15:25, 10:30] = band[15:25, 50:70] = True
    lab = np.broadcast_to(np.float32([50.0, 20.0, 30.0]), (40, 80, 3)).copy()
    lab[15:25, 10:30] = (30.0, 10.0, 15.0)
    lab[15:25, 50:70, 0] = 65.0
    src = _rgb(lab)
    ref = _rgb(np.ascontiguousarray(np.broadcast_to(np.float32([50.0, 8.0, 12.0]), (40, 80, 3))))
    plain = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf))
    out = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf, chroma_gain=(0.5, 1.0), highlight_knee=6.0))
    a = _lab(src)  # (the sRGB round trip moves the Lab values a little)
    dark, light = (slice(15, 25), slice(10, 30)), (slice(15, 25), slice(50, 70))
    np.testing.assert_allclose(np.median(plain[dark].reshape(-1, 3), 0), [30.0, -2.0, -3.0], atol=0.8)
    np.testing.assert_allclose(np.median(out[dark].reshape(-1, 3), 0), [30.0, 3.0, 4.5], atol=0.8)
    skin_l = float(np.median(a[~band][:, 0]))
    knee = skin_l + 6 * np.tanh((float(np.median(a[light][..., 0])) - skin_l) / 6)
    assert np.median(out[light][..., 0]) == pytest.approx(knee, abs=0.3)
    assert np.median(plain[light][..., 0]) == pytest.approx(65.0, abs=0.8)
    np.testing.assert_allclose(out[~band], _lab(ref)[~band], atol=0.8)  # the skin is the driver's


def test_highlight_knee_cuts_a_highlights_chroma_deficit_in_proportion_by_hand():
    """A white highlight (L 65, a* 10, b* 15) on a persona's skin (L 50, a* 20, b* 30), over a driver
    of L 50, a* 8, b* 12: the highlight's +15 L* is cut to 6 tanh(15 / 6) with ``highlight_knee`` 6,
    a share f = (15 - 6 tanh(15 / 6)) / 15 = 0.61 of it, and so is its a*, b* detail: a* = 8 + (1 - f)
    (10 - 20) = 4.1, b* = 12 + (1 - f) (15 - 30) = 6.1, not (-2, -3) (the grey band of a shiny brow
    ridge on a pale driver); without the knee, (-2, -3)."""
    band = np.zeros((40, 80), bool)
    band[15:25, 50:70] = True
    lab = np.broadcast_to(np.float32([50.0, 20.0, 30.0]), (40, 80, 3)).copy()
    lab[band] = (65.0, 10.0, 15.0)
    src = _rgb(lab)
    ref = _rgb(np.ascontiguousarray(np.broadcast_to(np.float32([50.0, 8.0, 12.0]), (40, 80, 3))))
    a = _lab(src)
    skin, light = np.median(a[~band], 0), np.median(a[band], 0)
    up = float(light[0] - skin[0])
    f = (up - 6 * np.tanh(up / 6)) / up
    assert f == pytest.approx(0.61, abs=0.02)
    plain = np.median(_lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf))[band], 0)
    out = np.median(_lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf, highlight_knee=6.0))[band], 0)
    np.testing.assert_allclose(plain[1:], [8 + light[1] - skin[1], 12 + light[2] - skin[2]], atol=0.8)
    np.testing.assert_allclose(out[1:], [8 + (1 - f) * (light[1] - skin[1]), 12 + (1 - f) * (light[2] - skin[2])],
                               atol=0.8)
    np.testing.assert_allclose(out[1:], [4.1, 6.1], atol=1.0)


def test_highlight_knee_map_knees_each_pixel_by_its_own_value():
    """Two equal highlights (+15 L*) under a knee map of 6 (left) and 2 (right): each is cut to its
    own knee x tanh(15 / knee) (5.92 and 2.0), as with that number everywhere."""
    band = np.zeros((40, 80), bool)
    band[15:25, 10:30] = band[15:25, 50:70] = True
    lab = np.broadcast_to(np.float32([50.0, 20.0, 30.0]), (40, 80, 3)).copy()
    lab[band, 0] = 65.0
    src = _rgb(lab)
    ref = _rgb(np.ascontiguousarray(np.broadcast_to(np.float32([50.0, 20.0, 30.0]), (40, 80, 3))))
    knee = np.full((40, 80), 6.0, np.float32)
    knee[:, 40:] = 2.0
    out = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf, highlight_knee=knee))
    for x, k in ((slice(10, 30), 6.0), (slice(50, 70), 2.0)):
        alone = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf, highlight_knee=k))
        np.testing.assert_allclose(out[15:25, x], alone[15:25, x], atol=1e-3)
    assert np.median(out[15:25, 50:70, 0]) == pytest.approx(50 + 2 * np.tanh(15 / 2), abs=0.8)


def test_brows_take_their_own_highlight_knee():
    """``_knee_map``: ``brow_highlight_knee`` inside the brow bands (their middle), the
    ``highlight_knee`` away from them (the cheek), a number without bands or with
    ``brow_highlight_knee`` None."""
    from _photos import simple_face68
    from facetex.puppet.composite import _knee_map
    from facetex.puppet.detail import brow_bands, feature_parts

    p = simple_face68()
    bands = brow_bands(np.ones((256, 256), bool), feature_parts(p, (256, 256)), feature_parts(p, (256, 256)))
    params = CompositeParams()
    m = _knee_map(params, bands, 80.0)
    assert m.shape == (256, 256)
    assert m[int(p[19, 1]) + 3, int(p[19, 0])] == pytest.approx(params.brow_highlight_knee, abs=0.05)
    assert m[150, 60] == pytest.approx(params.highlight_knee)
    assert _knee_map(params, None, 80.0) == params.highlight_knee
    assert _knee_map(CompositeParams(brow_highlight_knee=None), bands, 80.0) == params.highlight_knee


def test_shadow_knee_by_hand():
    """A dark persona (skin L 40) with a shadow band 20 L* under its skin (an under-eye circle) on a
    pale driver (L 75): the gain 75 / 40 is clipped to 1.2, so the band is 75 - 24 = 51 without the
    knee, 75 - 1.2 x 6 tanh(20 / 6) = 67.9 with ``shadows`` weight 1 and ``shadow_knee`` 6, 75 - 1.2 x
    (20 - 0.5 (20 - 6 tanh(20 / 6))) = 59.4 at weight 0.5; a lighter band (L 50) is untouched, and
    with ``keep_dark`` the rims' darker gain (the skins' ratio 1.875, under ``brow_gain`` 2) takes the
    compressed detail: 75 - 1.875 x 6 tanh(20 / 6) = 63.8."""
    band, src = _two_band_skin(40.0, 20.0, 50.0)
    ref = _flat_skin(75.0, band.shape)
    a = _lab(src)
    d = float(np.median(a[15:25, 10:30, 0])) - float(np.median(a[~band][:, 0]))  # ~ -20 (sRGB round trip)
    knee = 6 * np.tanh(-d / 6)
    plain = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf))
    assert np.median(plain[15:25, 10:30, 0]) == pytest.approx(75 + 1.2 * d, abs=0.5)
    for w, expect in ((1.0, 75 - 1.2 * knee), (0.5, 75 + 1.2 * (d + 0.5 * (-d - knee)))):
        out = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf, shadows=np.full(band.shape, w, np.float32),
                                        shadow_knee=6.0))
        assert np.median(out[15:25, 10:30, 0]) == pytest.approx(expect, abs=0.5)
        np.testing.assert_allclose(out[15:25, 50:70], plain[15:25, 50:70], atol=1e-3)  # lighter: untouched
    rims = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf, shadows=np.ones(band.shape, np.float32),
                                     keep_dark=band.astype(np.float32), brow_gain=2.0))
    ratio = 75.0 / float(np.median(a[~band][:, 0]))
    assert np.median(rims[15:25, 10:30, 0]) == pytest.approx(75 - ratio * knee, abs=0.5)
    # a like-toned or paler driver: the persona's shading as it is (no knee)
    for driver_l in (40.0, 30.0):
        like = _flat_skin(driver_l, band.shape)
        np.testing.assert_allclose(
            transfer_skin_colour(src, like, ~band, ~band, sigma=np.inf, shadows=np.ones(band.shape, np.float32)),
            transfer_skin_colour(src, like, ~band, ~band, sigma=np.inf), atol=1e-6)


def test_skin_weights_leave_out_the_features():
    """The shadow knee's weight: ~0 on the eyes, brows, lips and nostrils (their landmarks, some on
    the features' edges: under 0.15), 1 on the cheeks."""
    from facetex.puppet._pixels import _skin_weights
    from facetex.landmarks import detect_face
    from facetex.io import read_image_uint8
    from facetex._resources import sample_path

    img = read_image_uint8(sample_path("frl_004_neutral.jpg"))
    p = np.asarray(detect_face(img).points68, float)
    w = _skin_weights(p, img.shape[:2])
    at = lambda q: float(w[int(round(q[1])), int(round(q[0]))])  # noqa: E731
    for i in (37, 44, 19, 24, 51, 57, 33, 31, 35):  # lids, brows, lips, nose tip and nostrils
        assert at(p[i]) < 0.15, i
    iod = np.linalg.norm(p[45] - p[36])
    for q in (p[2] + (0.25 * iod, 0), p[14] - (0.25 * iod, 0)):  # the cheeks
        assert at(q) > 0.95


def test_brow_gain_by_hand():
    """A dark persona (skin L 40) with a dark brow (L 30) and a light patch (L 50) in its brow
    region, on a pale driver (L 75): the skin's lightness gain is 75 / 40 = 1.875, clipped to 1.2
    (brow 75 - 1.2 x 10 = 63); in the brows' weight 1 the darker-than-skin detail takes the gain up
    to ``brow_gain`` 2 (75 - 1.875 x 10 = 56.25), the lighter stays the skin's (75 + 1.2 x 10 = 87).
    On a darker driver (gain below 1.2) nothing changes."""
    band, src = _two_band_skin(40.0, 30.0, 50.0)
    for driver_l, brow, light in ((75.0, 56.25, 87.0), (44.0, 44.0 - 1.1 * 10, 44.0 + 1.1 * 10)):
        ref = _flat_skin(driver_l, band.shape)
        plain = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf))
        out = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf, brows=band.astype(np.float32),
                                        brow_gain=2.0))
        np.testing.assert_allclose(out[~band], plain[~band], atol=1e-3)
        assert np.median(out[15:25, 10:30, 0]) == pytest.approx(brow, abs=0.8)
        assert np.median(out[15:25, 50:70, 0]) == pytest.approx(light, abs=0.8)
        np.testing.assert_allclose(out[15:25, 50:70], plain[15:25, 50:70], atol=1e-3)
        drawn = []  # the weights as a function: the same result, drawn only when the gain applies
        lazy = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=np.inf, brow_gain=2.0,
                                         brows=lambda: drawn.append(1) or band.astype(np.float32)))
        np.testing.assert_array_equal(lazy, out)
        assert len(drawn) == (driver_l == 75.0)
    np.testing.assert_allclose(out, plain, atol=1e-3)  # the darker driver: as without brows


def test_eye_skin_takes_the_drivers_shading_under_the_eyes_by_hand():
    """A dark persona (skin L 40, noise 3 L*) with an under-eye circle 20 L* darker (band 15:25,
    10:30), left out of both skin masks as the feature margin leaves it, on a pale driver (L 75, noise 3) whose
    own skin is 10 L* darker there: the skins' fields are interpolated over the band, so without
    ``eye_skin`` the circle is 75 - 1.2 x 20 = 51; with the band as ``eye_skin``'s zone it takes the
    driver's 65 (the persona's own shading replaced, its noise kept). Outside the zone's box nothing
    changes; on a darker driver the weights are not drawn and nothing changes."""
    rng = np.random.default_rng(0)
    band = np.zeros((40, 80), bool)
    band[15:25, 10:30] = True
    lab = np.broadcast_to(np.float32([40.0, 12.0, 18.0]), (40, 80, 3)).copy()
    lab[..., 0] += rng.normal(0.0, 3.0, (40, 80)).astype(np.float32)
    lab[15:25, 10:30, 0] -= 20.0
    src = _rgb(lab)
    ref_lab = np.broadcast_to(np.float32([75.0, 14.0, 22.0]), (40, 80, 3)).copy()
    ref_lab[..., 0] += rng.normal(0.0, 3.0, (40, 80)).astype(np.float32)  # (a flat skin has no spread:
    ref_lab[15:25, 10:30, 0] -= 10.0  # its fields' outlier clip would cut the circle)
    ref = _rgb(ref_lab)
    zone = (band.astype(np.float32), np.zeros_like(band))
    plain = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=20.0))
    out = _lab(transfer_skin_colour(src, ref, ~band, ~band, sigma=20.0, eye_skin=zone, eye_skin_sigma=2.0))
    inner = (slice(18, 22), slice(14, 26))
    assert np.median(plain[inner][..., 0]) == pytest.approx(51.0, abs=1.5)
    assert np.median(out[inner][..., 0]) == pytest.approx(65.0, abs=1.5)
    grain = lambda x: x[inner][..., 0] - cv2.GaussianBlur(x[..., 0], (0, 0), 2.0)[inner]  # noqa: E731
    assert np.corrcoef(grain(out).ravel(), grain(_lab(src)).ravel())[0, 1] > 0.8  # its own fine detail
    np.testing.assert_allclose(out[:, 40:], plain[:, 40:], atol=1e-4)  # beyond the zone's box (pad 8 px)
    like = _flat_skin(35.0, band.shape)
    drawn = []
    np.testing.assert_array_equal(
        transfer_skin_colour(src, like, ~band, ~band, sigma=20.0, eye_skin=lambda: drawn.append(1) or zone),
        transfer_skin_colour(src, like, ~band, ~band, sigma=20.0))
    assert not drawn


def test_composite_keeps_the_drivers_skin_colour_inside_a_dark_outline():
    """The driver's face has a dark grey band 6 px wide along its outline (hair: not its skin
    colour); the puppet is a flat pale skin. By default the face's middle takes the driver's skin
    colour (ΔE < 2); the gradient-domain blend (``poisson=True``) keeps the puppet's gradients and
    takes the band as its border values, so the band's darkness fills the whole face (the middle's
    L* 35 under the driver's skin here: the darker, greyer cast on real drivers)."""
    frame, face, inner, coverage, kw = _oval_scene()
    yy, xx = np.mgrid[0:96, 0:96]
    middle = ((xx - 48) / 12.0) ** 2 + ((yy - 50) / 16.0) ** 2 <= 1
    rim = face & ~(((xx - 48) / 20.0) ** 2 + ((yy - 50) / 26.0) ** 2 <= 1)
    frame[rim] = (0.12, 0.12, 0.13)
    puppet = np.broadcast_to(np.float32([0.85, 0.75, 0.75]), frame.shape).copy()
    cp = dict(mouth=False, grain=0.0, sharpen=1.0, nose_sharpen=1.0, occlusion=False)
    out = composite_face(frame, puppet, coverage, None, params=CompositeParams(**cp), **kw)[0]
    pois = composite_face(frame, puppet, coverage, None, params=CompositeParams(poisson=True, **cp), **kw)[0]
    skin = _lab(frame)[middle].mean(axis=0)
    assert np.linalg.norm(_lab(out)[middle].mean(axis=0) - skin) < 2.0
    assert _lab(pois)[middle].mean(axis=0)[0] < skin[0] - 4.0


def test_composite_sharpens_the_puppets_skin_and_features_each_to_the_drivers():
    """The skin's sharpening gain (matched on the skin) is added on the skin only; the features get
    a gain of their own, matched on the features of both faces. A puppet's crisp dark brow (a 3 px
    bar on its brow line) on soft skin, a driver with grainy skin: on a driver whose brows are flat
    the bar's edges stay as without sharpening (within 0.01) while the skin is sharpened; with
    ``sharpen_feather=0`` (the skin's gain on the whole face, as before) they are over-drawn; on a
    driver whose brows carry strong fine detail, a soft bar is sharpened."""
    frame, face, inner, coverage, kw = _oval_scene()
    p = kw["driver_points68"].copy()
    p[0], p[16] = (24, 50), (72, 50)  # the face's width: the brows' thickness
    p[17:22] = np.c_[np.linspace(34, 44, 5), np.full(5, 34.0)]
    p[22:27] = np.c_[np.linspace(52, 62, 5), np.full(5, 34.0)]
    kw = {**kw, "driver_points68": p, "puppet_points68": p}
    rng = np.random.default_rng(5)
    frame[face] += rng.normal(0, 0.03, (int(face.sum()), 3)).astype(np.float32)
    flat = frame.copy()
    flat[30:39, 30:66] = (0.55, 0.4, 0.3)  # the driver's brows: no fine detail
    hairy = flat.copy()
    hairy[32:37, 33:64] += rng.normal(0, 0.15, (5, 31, 1)).astype(np.float32)
    frame, flat, hairy = (np.clip(x, 0, 1) for x in (frame, flat, hairy))
    puppet = np.broadcast_to(np.float32([0.6, 0.45, 0.35]), frame.shape).copy()
    puppet += cv2.GaussianBlur(rng.normal(0, 0.01, frame.shape).astype(np.float32), (0, 0), 1.0)
    crisp = puppet.copy()
    crisp[33:36, 34:45] = (0.2, 0.15, 0.1)
    soft = puppet.copy()
    soft[32:37, 34:45] = cv2.GaussianBlur(crisp, (0, 0), 1.2)[32:37, 34:45]
    bar = np.zeros(frame.shape[:2], bool)
    bar[[33, 35], 36:43] = True  # its edges
    skin = inner.copy()
    skin[26:42, 28:68] = False
    cp = dict(mouth=False, grain=0.0, nose_sharpen=1.0, occlusion=False, persona_hair=False, lip_detail=0.0,
              lid_detail=0.0, eyes="persona")

    def run(drv, pup, **kv):
        return composite_face(drv, pup, coverage, None, params=CompositeParams(**{**cp, **kv}), **kw)[0]

    plain, default = run(flat, crisp, sharpen=1.0), run(flat, crisp)
    assert _lap_var(default, skin) > 2.0 * _lap_var(plain, skin)  # the skin is sharpened
    assert np.abs(default - plain)[bar].max() < 0.01
    assert np.abs(run(flat, crisp, sharpen_feather=0.0) - plain)[bar].max() > 0.03
    assert np.abs(run(hairy, soft) - run(hairy, soft, sharpen=1.0))[bar].max() > 0.02
