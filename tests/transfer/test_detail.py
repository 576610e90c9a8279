"""Native-resolution detail stage (facetex.transfer.detail) on hand-made images."""

import numpy as np
import pytest

from facetex.errors import BadInputError
from facetex.transfer.detail import DetailParams, band_energy, band_stack, transfer_skin_detail


def _noise(seed, amp, shape=(96, 96)):
    rng = np.random.default_rng(seed)
    n = rng.normal(0, amp, shape + (1,)).astype(np.float32)
    return np.clip(0.5 + np.repeat(n, 3, 2), 0, 1)


def test_bands_sum_back_to_the_image():
    img = _noise(0, 0.05)
    bands, rest = band_stack(img, (1.0, 2.0, 4.0))
    assert np.allclose(sum(bands) + rest, img, atol=1e-5)


def test_band_energy_of_a_constant_is_zero_and_of_noise_positive():
    assert np.allclose(band_energy(np.zeros((20, 20, 3), np.float32), 2.0), 0)
    b, _ = band_stack(_noise(1, 0.05), (1.0,))
    assert band_energy(b[0], 2.0).mean() > 1e-4


def test_full_skin_takes_the_style_detail_and_keeps_the_coarse_output():
    out = np.full((96, 96, 3), 0.6, np.float32)  # flat output
    style = _noise(2, 0.04)
    ones = np.ones((96, 96), np.float32)
    res = transfer_skin_detail(out, style, ones, ones, face_width=330.0, params=DetailParams(relative=0.0))
    fine_res, coarse_res = band_stack(res, (1.0, 2.0, 4.0))
    fine_sty, _ = band_stack(style, (1.0, 2.0, 4.0))
    # the finest band is the style's (gain 1: the style energy is its own)
    assert np.allclose(fine_res[0][8:-8, 8:-8], fine_sty[0][8:-8, 8:-8], atol=2e-3)
    # the coarse part is still the output's mean
    assert abs(float(coarse_res.mean()) - 0.6) < 0.01
    # relative detail (the default) on a darker output: the style's contrast, its band times 0.3 / 0.5
    dark = np.full((96, 96, 3), 0.3, np.float32)
    rel = band_stack(transfer_skin_detail(dark, style, ones, ones, face_width=330.0), (1.0, 2.0, 4.0))[0]
    assert np.allclose(rel[0][8:-8, 8:-8], 0.6 * fine_sty[0][8:-8, 8:-8], atol=3e-3)


def test_relative_detail_follows_the_local_colour_and_is_bounded():
    """A pale style's pores on a dark face keep their contrast, not their amplitude; the scale is
    clipped, and never above 1 (a dark style's noise is not amplified on a pale face)."""
    style = _noise(5, 0.03)  # mean 0.5
    ones = np.ones((96, 96), np.float32)
    fine_sty = band_stack(style, (1.0,))[0][0][8:-8, 8:-8].std()
    for level, want in ((0.25, 0.5), (0.05, 0.25), (0.8, 1.0)):  # 0.05 / 0.5 = 0.1 is clipped to 0.25
        out = np.full((96, 96, 3), level, np.float32)
        res = transfer_skin_detail(out, style, ones, ones, face_width=330.0)
        got = band_stack(res, (1.0,))[0][0][8:-8, 8:-8].std() / fine_sty
        assert abs(got - want) < 0.08 * want, (level, got, want)


def test_style_energy_gain_restores_a_lost_energy():
    out = np.full((96, 96, 3), 0.5, np.float32)
    style = _noise(3, 0.03)
    ones = np.ones((96, 96), np.float32)
    sig = DetailParams().sigmas
    b, _ = band_stack(style, sig)
    target = [4.0 * band_energy(bk, 2.0 * s) for bk, s in zip(b, sig)]  # 2x amplitude
    res = transfer_skin_detail(out, style, ones, ones, style_energy=target, face_width=330.0)
    rb, _ = band_stack(res, sig)
    ratio = rb[0][10:-10, 10:-10].std() / b[0][10:-10, 10:-10].std()
    assert 1.8 < ratio < 2.2


def test_nothing_changes_outside_the_content_skin():
    out = _noise(4, 0.02)
    style = _noise(5, 0.06)
    mc = np.zeros((96, 96), np.float32)
    mc[30:60, 30:60] = 1.0
    res = transfer_skin_detail(out, style, mc, np.ones_like(mc), face_width=330.0)
    assert np.array_equal(res[mc == 0], out[mc == 0])
    assert np.abs(res[35:55, 35:55] - out[35:55, 35:55]).max() > 0.01


def test_where_the_style_is_not_skin_the_output_keeps_its_own_detail_rescaled():
    out = _noise(6, 0.01)
    style = _noise(7, 0.04)
    ones = np.ones((96, 96), np.float32)
    res = transfer_skin_detail(out, style, ones, np.zeros_like(ones), face_width=330.0)
    ro, _ = band_stack(res, (1.0,))
    oo, _ = band_stack(out, (1.0,))
    c = (slice(10, -10), slice(10, -10))
    # same pattern as the output (correlation ~1), amplitude moved towards the style's (x1.25 cap)
    corr = np.corrcoef(ro[0][c][..., 0].ravel(), oo[0][c][..., 0].ravel())[0, 1]
    assert corr > 0.95 and ro[0][c].std() > 1.2 * oo[0][c].std()


def test_strength_zero_is_identity_and_bad_shapes_raise():
    out, style = _noise(8, 0.02), _noise(9, 0.05)
    ones = np.ones((96, 96), np.float32)
    assert np.allclose(transfer_skin_detail(out, style, ones, ones, params=DetailParams(strength=0.0)), out)
    with pytest.raises(BadInputError):
        transfer_skin_detail(out, style[:50], ones, ones)
    with pytest.raises(BadInputError):
        transfer_skin_detail(out, style, ones[:50], ones)


# ---------------------------------------------------------------- the style's hair is never a source (issue 22)
def _stripes(shape=(96, 96), period=5.0, amp=0.15):
    x = np.arange(shape[1])[None, :]
    s = amp * np.sin(2 * np.pi * x / period) * np.ones(shape)
    return np.repeat(s[..., None], 3, 2).astype(np.float32)


def test_fill_from_source_takes_skin_texture_not_the_hole():
    from facetex.transfer.detail import fill_from_source

    skin = _noise(10, 0.04) - 0.5
    img = skin.copy()
    src = np.zeros((96, 96), bool)
    src[:, :40] = True
    img[:, 40:] = _stripes()[:, 40:]  # "hair" in the hole
    filled = fill_from_source([img], src, ~src, block=16, mirror_max=4.0)[0]
    assert np.array_equal(filled[:, :40], img[:, :40])  # the source is untouched
    hole = filled[:, 48:, 0]
    corr = np.corrcoef(hole.ravel(), _stripes()[:, 48:, 0].ravel())[0, 1]
    assert abs(corr) < 0.1  # nothing of the stripes is left
    assert 0.7 < hole.std() / skin[:, :40, 0].std() < 1.3  # the skin's texture energy, no blur
    # near the edge the texture is mirrored: column 41 (2 px past the last source column 39) reads column 37
    assert np.array_equal(filled[:, 41], img[:, 37])


def test_style_hair_never_reaches_the_output():
    """Stripes where the style's mask says hair: the output gets the style's skin detail there instead."""
    out = np.full((96, 96, 3), 0.6, np.float32)
    skin = _noise(11, 0.03)
    style = skin.copy()
    ms = np.ones((96, 96), np.float32)
    ms[:, 30:70] = 0.0
    style[:, 30:70] = 0.6 + _stripes()[:, 30:70]  # the style's fringe
    ones = np.ones((96, 96), np.float32)
    res = transfer_skin_detail(out, style, ones, ms, face_width=330.0)
    change = (res - out)[10:-10, 40:60, 0]
    corr = np.corrcoef(change.ravel(), _stripes()[10:-10, 40:60, 0].ravel())[0, 1]
    assert abs(corr) < 0.1
    fine, _ = band_stack(res, (1.0, 2.0))
    sfine, _ = band_stack(skin, (1.0, 2.0))
    assert fine[0][10:-10, 40:60].std() > 0.6 * sfine[0][10:-10, 10:25].std()  # skin detail, not nothing
    without = transfer_skin_detail(out, style, ones, ms, face_width=330.0, params=DetailParams(fill=False))
    assert np.abs(without - out)[10:-10, 40:60].max() < 1e-6  # (old behaviour: the flat output's own detail)


def test_the_own_zone_keeps_the_outputs_detail_and_the_rest_takes_the_styles():
    """The content's beard zone: no style pore (a speck there reads as stubble), no fill."""
    out = _noise(12, 0.01)
    style = _noise(13, 0.05)
    ones = np.ones((96, 96), np.float32)
    zone = np.zeros((96, 96), bool)
    zone[:, 48:] = True
    res = transfer_skin_detail(out, style, ones, ones, face_width=330.0, own_zone=zone)
    ro, _ = band_stack(res, (1.0,))
    oo, _ = band_stack(out, (1.0,))
    so, _ = band_stack(style, (1.0,))
    inside, outside = (slice(10, -10), slice(70, -10)), (slice(10, -10), slice(10, 30))
    corr = lambda a, b, c: np.corrcoef(a[c][..., 0].ravel(), b[c][..., 0].ravel())[0, 1]  # noqa: E731
    assert corr(ro[0], oo[0], inside) > 0.95 and abs(corr(ro[0], so[0], inside)) < 0.1
    assert corr(ro[0], so[0], outside) > 0.95
    assert abs(ro[0][inside].std() / oo[0][inside].std() - 1.0) < 0.05  # as it is: not rescaled
    with pytest.raises(BadInputError):
        transfer_skin_detail(out, style, ones, ones, own_zone=zone[:50])
    # with own_detail (the pipeline's content), the zone takes that image's bands instead of the
    # output's (the optimiser's chroma speckle there is not the content's); outside nothing changes
    content = _noise(14, 0.02)
    res2 = transfer_skin_detail(out, style, ones, ones, face_width=330.0, own_zone=zone, own_detail=content)
    r2, _ = band_stack(res2, (1.0,))
    co, _ = band_stack(content, (1.0,))
    assert corr(r2[0], co[0], inside) > 0.95 and abs(corr(r2[0], oo[0], inside)) < 0.1
    assert abs(r2[0][inside].std() / co[0][inside].std() - 1.0) < 0.05
    np.testing.assert_allclose(res2[:, :30], res[:, :30], atol=1e-6)
    with pytest.raises(BadInputError):
        transfer_skin_detail(out, style, ones, ones, own_zone=zone, own_detail=content[:50])


def test_the_fill_takes_the_styles_fine_bands_but_not_its_lines():
    """Holes in the style's skin get its pores (fine bands) from the fill, while its coarse band
    there (folds and lines: dark strokes on a cheek, FRL 042 <- 003) stays the output's own."""
    yy, xx = np.mgrid[0:128, 0:128].astype(np.float32)
    lines = 0.06 * np.sin(2 * np.pi * (xx + yy) / 40.0)  # diagonal lines of the [4, 8] px band
    style = np.clip(_noise(21, 0.02, (128, 128)) + lines[..., None], 0, 1)
    ms = np.ones((128, 128), np.float32)
    ms[:, 64:] = 0.0  # the style's hair: a hole the fill covers
    out = np.full((128, 128, 3), 0.6, np.float32)
    ones = np.ones((128, 128), np.float32)
    hole = (slice(16, -16), slice(84, 112))

    def in_hole(p):
        change = (transfer_skin_detail(out, style, ones, ms, face_width=330.0, params=p) - out)[..., 0][hole]
        ref = lines[hole] - lines[hole].mean()
        local = (change * ref).sum() / (ref * ref).sum()  # how much of the lines, in place
        fine, _ = band_stack(np.repeat(change[..., None], 3, 2), (1.0,))
        return abs(float(local)), float(fine[0].std()), float(np.abs(change).max())

    new, old = in_hole(DetailParams()), in_hole(DetailParams(fill_max_sigma=99.0))
    assert new[0] < 0.3 * old[0]  # the style's lines do not go on into the hole (measured 0.02 vs 0.15)
    assert new[2] < old[2]  # and its strongest stroke there is weaker
    assert new[1] > 0.004 and abs(new[1] - old[1]) < 0.25 * old[1]  # the pores are filled as before
