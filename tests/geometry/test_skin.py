"""Skin masks (facetex.geometry.skin): features excluded, hair excluded, highlights kept."""

import cv2
import numpy as np
import pytest

from facetex._resources import sample_path
from facetex.errors import BadInputError
from facetex.geometry.masks import face_width
from facetex.geometry.skin import feature_mask, face_region_mask, protected_mask, skin_colour_distance
from facetex.geometry.segment import head_region_mask, skin_mask
from facetex.landmarks import detect_face, face_mesh468


@pytest.fixture(scope="module")
def face():
    img = cv2.imread(str(sample_path("frl_004_neutral.jpg")))[..., ::-1].astype(np.float32) / 255.0
    f = detect_face(img)
    return img, f.points68, face_mesh468(img, f)


def test_mask_is_zero_on_every_feature_and_outside_the_face(face):
    img, p, mesh = face
    m = skin_mask(img, p, mesh=mesh)
    assert m.dtype == np.float32 and m.shape == img.shape[:2]
    assert 0.0 <= m.min() and m.max() <= 1.0
    assert m[protected_mask(p, img.shape)].max() == 0.0  # eyes, brows, lips
    assert m[feature_mask(p, img.shape)].max() == 0.0  # grown features incl. nostrils
    assert m[~head_region_mask(p, img.shape, mesh=mesh)].max() == 0.0  # the whole skin, no further
    # most of both cheeks is skin
    for idx in ((2, 31, 41, 48), (14, 35, 46, 54)):
        x, y = np.round(p[list(idx)].mean(0)).astype(int)
        assert m[y, x] > 0.9


def test_dark_hair_over_the_forehead_is_not_skin(face):
    img, p, mesh = face
    img = cv2.resize(img, None, fx=2.5, fy=2.5, interpolation=cv2.INTER_CUBIC)  # FRL's own 1000 px
    p, mesh = (p + 0.5) * 2.5 - 0.5, (mesh + 0.5) * 2.5 - 0.5
    fw = face_width(p)
    band = face_region_mask(p, img.shape, mesh=mesh) & ~feature_mask(p, img.shape)
    band[int(p[17:27, 1].min() - 0.1 * fw):] = False  # the forehead above the brows
    assert band.sum() > 2000
    hair = img.copy()
    hair[band] = (0.18, 0.12, 0.08)  # a dark-brown fringe
    with_colour = skin_mask(hair, p, mesh=mesh, soft=False)
    without = skin_mask(hair, p, mesh=mesh, colour=False, soft=False)
    assert with_colour[band].mean() < 0.02
    assert without[band].mean() > 0.9  # the face oval alone would take it as skin


def test_a_specular_highlight_stays_skin(face):
    img, p, mesh = face
    hl = img.copy()
    c = np.round(p[[2, 31, 41, 48]].mean(0)).astype(int)
    cv2.circle(hl, tuple(int(v) for v in c), 4, (1.0, 1.0, 1.0), -1)
    m = skin_mask(hl, p, mesh=mesh, soft=False)
    assert m[c[1], c[0]]


def test_colour_distance_separates_skin_from_black_and_green(face):
    img, p, _ = face
    test = img.copy()
    test[:10, :10] = (0.02, 0.02, 0.02)
    test[:10, -10:] = (0.1, 0.6, 0.1)
    dist, z = skin_colour_distance(test, p)
    c = np.round(p[[14, 35, 46, 54]].mean(0)).astype(int)
    assert dist[c[1], c[0]] < 2.0 and abs(z[c[1], c[0]]) < 2.0
    assert z[:10, :10].max() < -4.0  # much darker than the skin
    assert dist[:10, -10:].min() > 10.0  # far in chromaticity


def test_landmark_outline_fallback_without_mesh(face):
    img, p, _ = face
    m = skin_mask(img, p, mesh=None)
    assert m.max() > 0.9 and m[protected_mask(p, img.shape)].max() == 0.0


def test_bad_input(face):
    img, p, _ = face
    with pytest.raises(BadInputError):
        skin_mask(img, p[:10])
    with pytest.raises(BadInputError):
        skin_mask(img[..., 0], p)


# ---------------------------------------------------------------- segmentation (issue 22)
def _sample(name):
    img = cv2.imread(str(sample_path(name)))[..., ::-1].astype(np.float32) / 255.0
    f = detect_face(img)
    return img, f.points68, face_mesh468(img, f)


@pytest.fixture(scope="module")
def clean():
    return _sample("frl_005_neutral.jpg")  # a young man, clean-shaven, no fringe


def _forehead_box(p):
    fw = face_width(p)
    y1 = int(p[17:27, 1].min() - 0.06 * fw)
    return slice(y1 - int(0.12 * fw), y1), slice(int(p[19, 0]), int(p[24, 0]))


def test_segment_bundled_samples_fringe_and_stubble():
    from facetex.geometry.segment import segment_face

    img, p, mesh = _sample("frl_003_neutral.jpg")  # a fringe down to the brows
    seg = segment_face(img, p, mesh=mesh)
    assert seg.hair[_forehead_box(p)].mean() > 0.6
    for idx in ((2, 31, 41, 48), (14, 35, 46, 54)):
        x, y = np.round(p[list(idx)].mean(0)).astype(int)
        assert seg.skin[y, x] and not seg.beard[y, x]
    img, p, mesh = _sample("frl_004_neutral.jpg")  # stubble and a beard
    seg = segment_face(img, p, mesh=mesh)
    chin = (slice(int(p[57, 1]) + 5, int(p[8, 1]) - 5), slice(int(p[7, 0]), int(p[9, 0])))
    assert seg.beard[chin].mean() > 0.7
    assert seg.skin[_forehead_box(p)].mean() > 0.8  # his forehead is bare


def test_a_striped_skin_coloured_fringe_is_hair(clean):
    """Blond strands pass the colour test: the structure tensor finds them."""
    from facetex.geometry.segment import segment_face

    img, p, mesh = clean
    fw = face_width(p)
    ys, xs = _forehead_box(p)
    ys = slice(int(p[17:27, 1].min() - 0.5 * fw), ys.stop)  # from above the hairline down
    striped = img.copy()
    patch = striped[ys, xs]
    x = np.arange(patch.shape[1])[None, :, None]
    patch[:] = np.clip(patch * (1.0 + 0.35 * np.sin(2 * np.pi * x / 5.0)), 0, 1)  # strands 2-3 px wide
    seg0 = segment_face(img, p, mesh=mesh)
    seg = segment_face(striped, p, mesh=mesh)
    fb = _forehead_box(p)
    assert seg0.skin[fb].mean() > 0.8
    assert seg.hair[fb].mean() > 0.7 and seg.skin[fb].mean() < 0.2


def test_dark_specks_on_a_clean_chin_are_stubble(clean):
    from facetex.geometry.segment import segment_face

    img, p, mesh = clean
    chin = (slice(int(p[57, 1]) + 3, int(p[8, 1]) - 3), slice(int(p[6, 0]), int(p[10, 0])))
    speckled = img.copy()
    rng = np.random.default_rng(0)
    patch = speckled[chin]
    dots = rng.random(patch.shape[:2]) < 0.12
    patch[dots] *= 0.55  # dark 1-px hairs, ~12 % of the pixels
    seg0 = segment_face(img, p, mesh=mesh)
    seg = segment_face(speckled, p, mesh=mesh)
    assert seg0.beard[chin].mean() < 0.15  # (a shadow under the jaw at 130 px face width)
    assert seg.beard[chin].mean() > 0.6


def test_a_bright_low_chroma_blob_is_a_highlight_and_no_texture_source(clean):
    from facetex.geometry.segment import segment_face

    img, p, mesh = clean
    fw = face_width(p)
    c = np.round(p[[14, 35, 46, 54]].mean(0)).astype(int)
    shiny = img.copy()
    yy, xx = np.mgrid[: img.shape[0], : img.shape[1]]
    blob = np.exp(-((yy - c[1]) ** 2 + (xx - c[0]) ** 2) / (2 * (0.02 * fw) ** 2))[..., None]
    shiny = np.clip(shiny * (1 - blob) + blob * 0.97, 0, 1).astype(np.float32)  # white reflection
    seg = segment_face(shiny, p, mesh=mesh)
    assert seg.highlight[c[1], c[0]] and seg.skin[c[1], c[0]]  # still the content's skin
    assert not seg.source(0.02, fw)[c[1], c[0]]  # but never a style's texture source
    src = skin_mask(shiny, p, mesh=mesh, source=True, soft=False)
    assert not src[c[1], c[0]]


def test_the_beard_zone_is_skin_but_never_a_texture_source(clean):
    """Stubble may pass every colour and speck test (short, grey, or dark on dark skin): the
    upper lip and chin of a style lend no texture, whatever is found there."""
    from facetex.geometry.skin import SkinParams
    from facetex.geometry.segment import segment_face

    img, p, mesh = clean
    fw = face_width(p)
    seg = segment_face(img, p, mesh=mesh)
    src = seg.source(0.02, fw)
    lip = np.round((p[33] + p[51]) / 2).astype(int)
    chin = np.round((p[57] + p[8]) / 2).astype(int)
    cheek = np.round(p[[2, 31, 41, 48]].mean(0)).astype(int)
    for x, y in (lip, chin):
        assert seg.skin[y, x] and not src[y, x]
    assert src[cheek[1], cheek[0]]
    off = segment_face(img, p, mesh=mesh, params=SkinParams(source_beard_zone=False)).source(0.02, fw)
    assert off[chin[1], chin[0]]  # the zone, not another test, took it out


def test_segmenting_the_head_box_gives_the_labels_of_the_whole_image(clean):
    from facetex.geometry.segment import segment_face

    img, p, mesh = clean
    pad = 150  # a portrait with room around the head, as FRL's 1000 px ones
    big = cv2.copyMakeBorder(img, pad, pad, pad, pad, cv2.BORDER_REFLECT)
    pb, mb = p + pad, mesh + [pad, pad, 0]
    a = segment_face(big, pb, mesh=mb)
    b = segment_face(big, pb, mesh=mb, crop=False)
    assert b.region.any() and b.region.sum() < 0.5 * b.region.size  # the box is a crop
    for k in b.__dataclass_fields__:
        if getattr(b, k) is not None:
            assert np.array_equal(getattr(a, k), getattr(b, k)), k
