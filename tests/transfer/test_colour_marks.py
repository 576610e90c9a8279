"""Issue 22 finishing steps: the content's shading kept (transfer/colour.py), marks kept or
replaced (geometry/marks.py, transfer/marks.py) — hand-computed cases."""

import numpy as np
import pytest

from facetex.errors import BadInputError
from facetex.geometry.filters import masked_lowpass
from facetex.geometry.marks import detect_marks, marks_mask, match_marks
from facetex.transfer.colour import eye_distance, keep_content_shading
from facetex.transfer.marks import transfer_marks


def _blob(shape, x, y, sigma, depth):
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    return depth * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * sigma**2))


def test_masked_lowpass_ignores_what_lies_outside_the_mask():
    img = np.full((60, 60), 100.0, np.float32)
    mask = np.zeros((60, 60), np.float32)
    mask[:, :30] = 1
    img[:, :30] = 0.25  # inside: 0.25; outside: 100, which a plain blur would pull in
    low = masked_lowpass(img, mask, 5.0)
    assert np.allclose(low[:, :30], 0.25, atol=1e-5)
    # far from the mask there is nothing to average: 0
    assert np.all(low[:, 59] == 0.0)
    # colour images: per channel, the same weights
    rgb = np.stack([img, 2 * img, 3 * img], -1)
    low3 = masked_lowpass(rgb, mask, 5.0)
    assert np.allclose(low3[:, :30], [0.25, 0.5, 0.75], atol=1e-5)
    with pytest.raises(BadInputError):
        masked_lowpass(img, mask[:10], 5.0)


def test_keep_shading_removes_a_colour_shift_and_keeps_detail():
    rng = np.random.default_rng(0)
    content = np.full((80, 80, 3), 0.5, np.float32) + rng.normal(0, 0.02, (80, 80, 3)).astype(np.float32)
    skin = np.zeros((80, 80), np.float32)
    skin[10:70, 10:70] = 1
    checker = 0.05 * ((np.indices((80, 80)).sum(0) % 2) * 2 - 1)[..., None].astype(np.float32)
    shift = np.array([0.1, -0.05, 0.02], np.float32)  # an ashen / hue drift
    output = content + skin[..., None] * (shift + checker)
    got = keep_content_shading(output, content, skin, sigma=6.0)
    inner = (slice(20, 60), slice(20, 60))
    # the shift is gone: mean change 0 per channel
    assert np.abs((got - content)[inner].mean((0, 1))).max() < 1e-3
    # the pixel-scale detail (the checkerboard) stays
    assert np.allclose((got - content)[inner], checker[inner], atol=0.01)
    # outside the skin nothing changes
    assert np.array_equal(got[skin == 0], output[skin == 0])


def test_eye_distance_hand_computed():
    p = np.zeros((68, 2))
    p[36:42] = [10.0, 20.0]
    p[42:48] = [13.0, 24.0]
    assert eye_distance(p) == pytest.approx(5.0)
    with pytest.raises(BadInputError):
        eye_distance(np.zeros((5, 2)))


def test_detect_marks_finds_a_mole_not_pores_nor_what_is_off_the_skin():
    rng = np.random.default_rng(1)
    shape = (120, 120)
    img = 0.7 + rng.normal(0, 0.01, shape)  # pores: pixel noise
    img -= _blob(shape, 50, 60, 3.0, 0.3)  # a mole, σ 3 px
    img -= _blob(shape, 100, 20, 3.0, 0.3)  # the same off the skin
    skin = np.zeros(shape, np.float32)
    skin[:, :80] = 1
    marks = detect_marks(np.stack([img] * 3, -1).astype(np.float32), skin)
    assert marks.shape == (1, 3)
    x, y, r = marks[0]
    assert abs(x - 50) <= 1 and abs(y - 60) <= 1
    assert 2.0 < r < 6.0  # radius √2 σ ≈ 4.2 within the scale sampling
    assert len(detect_marks(np.full(shape, 0.7, np.float32), skin)) == 0


def test_marks_mask_and_matching_hand_computed():
    m = marks_mask([[20.0, 20.0, 2.0]], (40, 40))  # disc of radius 4, ramp ±1 px
    assert m[20, 20] == 1.0 and m[20, 23] == 1.0 and m[20, 26] == 0.0 and m[0, 0] == 0.0
    assert m[20, 24] == pytest.approx(0.5)
    a = np.array([[10.0, 10.0, 2.0], [30.0, 30.0, 2.0]])
    b = np.array([[12.0, 11.0, 2.0]])  # 2.24 px from the first: within 1.5 × 2
    assert match_marks(a, b).tolist() == [True, False]
    assert match_marks(a, np.zeros((0, 3))).tolist() == [False, False]


def test_transfer_marks_keeps_the_contents_or_brings_the_styles():
    rng = np.random.default_rng(2)
    shape = (100, 100)
    base = (0.6 + rng.normal(0, 0.01, shape)).astype(np.float32)
    mole_c = _blob(shape, 30, 30, 3.0, 0.3).astype(np.float32)
    mole_s = _blob(shape, 70, 70, 3.0, 0.3).astype(np.float32)
    content = np.stack([base - mole_c] * 3, -1)
    style = np.stack([base - mole_s] * 3, -1)
    output = np.stack([base - mole_s] * 3, -1)  # the transfer erased the content's mole and brought the style's
    skin = np.ones(shape, np.float32)
    kept, info = transfer_marks(output, content, style, skin, skin, mode="content", return_info=True)
    assert len(info["content"]) == 1 and len(info["style"]) == 1
    assert kept[30, 30, 0] == pytest.approx(content[30, 30, 0], abs=0.03)  # the content's mole is back
    assert kept[70, 70, 0] == pytest.approx(0.6, abs=0.03)  # the style's is gone
    moved = transfer_marks(np.stack([base] * 3, -1), content, style, skin, skin, mode="style")
    assert moved[70, 70, 0] == pytest.approx(style[70, 70, 0], abs=0.03)
    assert moved[30, 30, 0] == pytest.approx(0.6, abs=0.03)
    with pytest.raises(BadInputError):
        transfer_marks(output, content, style, skin, skin, mode="both")


def test_keep_shading_splits_luminance_and_chroma_scales():
    # a grey (luminance-only) ramp over 60 px survives a 2 px chroma low-pass but not a 30 px
    # luminance one; a chroma-only shift goes at the chroma σ
    h, w = 40, 120
    content = np.full((h, w, 3), 0.5, np.float32)
    skin = np.ones((h, w), np.float32)
    wave = 0.05 * np.sin(2 * np.pi * np.arange(w) / 12.0)[None, :, None].astype(np.float32)  # 12 px period
    grey = content + wave * np.ones(3, np.float32)
    kept = keep_content_shading(grey, content, skin, sigma=30.0, colour_sigma=2.0)
    assert np.allclose(kept[:, 30:90], grey[:, 30:90], atol=2e-3)  # finer than σy: kept as detail
    gone = keep_content_shading(grey, content, skin, sigma=1.0, colour_sigma=30.0)
    assert np.abs(gone - content)[:, 30:90].max() < 0.02  # below σy = 1 px's reach: removed
    tint = content + np.array([0.06, -0.03, 0.0], np.float32)  # constant: removed at any σ
    got = keep_content_shading(tint, content, skin, sigma=30.0, colour_sigma=2.0)
    assert np.abs(got - content).max() < 1e-3


def test_presets_keep_the_contents_shading_and_marks_and_preview_is_small():
    from facetex.transfer.methods import preset

    d, v, p = preset("facetex", "default"), preset("facetex", "preview"), preset("facetex", "paper")
    assert d.keep_shading and d.marks == "content" and d.converge == (10, 0.02)
    assert v.keep_shading and v.marks == "content" and v.size == 256 and sum(v.iters) < sum(d.iters) / 4
    assert v.detail and v.constraint == "skin"  # the default's steps, smaller
    assert not p.keep_shading and p.marks == "off"  # the paper's method as published
    assert not preset("mrf", "default").keep_shading
    assert not d.with_options(keep_shading=False).keep_shading and d.with_options(marks="style").marks == "style"
    with pytest.raises(BadInputError, match="marks must be"):
        d.with_options(marks="both")
    with pytest.raises(BadInputError, match="shading_sigma"):
        d.with_options(shading_sigma=0.0)
