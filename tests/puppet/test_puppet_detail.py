"""facetex.puppet.detail: the frame's grain on a puppet that its own bounded sharpening left smoother,
the driver's lip lines on the puppet's lips and its lash lines round the puppet's eyes."""

from __future__ import annotations

import cv2
import numpy as np

from facetex.puppet.detail import (GRAIN_BAND_SIGMAS, GRAIN_CLIP, _eye_affine, _fill_shifted, brow_bands, feature_parts,
                                   grain_fill, match_grain, match_grain_bands, match_lid_detail, match_lip_detail)
from facetex.geometry.masks import polygon_mask

from _photos import simple_face68


def _checker(h=40, w=48) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w]
    return np.where((yy + xx) % 2 == 0, 1.0, -1.0).astype(np.float32)[..., None] * np.ones(3, np.float32)


def test_match_grain_adds_the_frames_fine_band_by_the_hand_computed_amount():
    """Checkerboards c = +-1: the frame 0.5 + 0.1 c, the puppet 0.5 + 0.04 c. The frame's band
    (x minus its 4 neighbours' mean) is 0.2 c, under the clip (2.5 x 1.4826 x 0.2); the
    4-neighbour Laplacians are -8 x 0.04 c and -8 x 0.2 c, so Var(lap(src + a band)) =
    64 (0.04 + 0.2 a)^2 equals the frame's 64 x 0.1^2 at a = 0.3 (0.306: the image border's
    reflected pixels break the pattern there), and inside, the result is the frame's checkerboard."""
    c = _checker()
    ref, src = 0.5 + 0.1 * c, 0.5 + 0.04 * c
    skin = np.ones(c.shape[:2], bool)
    out, a = match_grain(src, ref, skin)
    assert abs(a - 0.3) < 0.01
    np.testing.assert_allclose(out[2:-2, 2:-2], 0.5 + (0.04 + 0.2 * a) * c[2:-2, 2:-2], atol=1e-5)
    np.testing.assert_allclose(out[2:-2, 2:-2], ref[2:-2, 2:-2], atol=0.002)
    capped, a1 = match_grain(src, ref, skin, max_amount=0.1)  # bounded
    assert a1 == 0.1
    np.testing.assert_allclose(capped[2:-2, 2:-2], 0.5 + 0.06 * c[2:-2, 2:-2], atol=1e-5)


def test_match_grain_leaves_a_puppet_as_detailed_as_the_frame_alone():
    c = _checker()
    src, ref = 0.5 + 0.1 * c, 0.5 + 0.05 * c
    out, a = match_grain(src, ref, np.ones(c.shape[:2], bool))
    assert a == 0.0 and np.array_equal(out, src)
    out, a = match_grain(src, 0.5 + 0.2 * c, np.zeros(c.shape[:2], bool))  # no skin: nothing
    assert a == 0.0 and np.array_equal(out, src)


def test_match_grain_clips_the_frames_strong_lines_and_stays_on_the_skin():
    """A dark 1 px line (a glasses rim) across the frame's grainy skin comes through clipped to
    GRAIN_CLIP robust standard deviations of the grain, not at its own depth; pixels more than 4 px
    (the feather's reach) from the skin are untouched."""
    rng = np.random.default_rng(0)
    h, w = 60, 64
    grain = rng.normal(0, 0.02, (h, w, 1)).astype(np.float32) * np.ones(3, np.float32)
    ref = 0.6 + grain
    ref[30] = 0.1  # the rim
    src = np.full((h, w, 3), 0.6, np.float32)
    skin = np.zeros((h, w), bool)
    skin[:, :40] = True
    out, a = match_grain(src, ref, skin)
    assert 0 < a <= 1
    band = ref - 0.25 * (np.roll(ref, 1, 0) + np.roll(ref, -1, 0) + np.roll(ref, 1, 1) + np.roll(ref, -1, 1))
    sd = 1.4826 * np.median(np.abs(band[5:25, 5:35, 0]))
    assert np.abs(out[30, 5:35] - 0.6).max() <= a * GRAIN_CLIP * sd * 1.1  # the rim: clipped
    assert np.abs(out[30, 5:35] - 0.6).max() < 0.2 * 0.5  # far below its 0.5 depth
    np.testing.assert_array_equal(out[:, 45:], src[:, 45:])
    assert np.std(out[5:25, 5:35] - src[5:25, 5:35]) > 0.01  # grain where the skin is


def test_fill_shifted_copies_rigid_pieces_of_the_source_nearest_offset_first():
    """A 4-row hole under 10 source rows: with step 5 the first offset (up 5 px) lands on the source
    for every hole pixel, so the hole is the band 5 rows up, copied rigidly (not the boundary row
    repeated); a hole pixel with no source at any offset stays as it was."""
    band = np.arange(20 * 12, dtype=np.float32).reshape(20, 12)
    source = np.zeros((20, 12), bool)
    source[:10] = True
    hole = np.zeros((20, 12), bool)
    hole[10:14] = True
    out = _fill_shifted(band, grain_fill(source, hole, 5.0))
    np.testing.assert_array_equal(out[10:14], band[5:9])
    np.testing.assert_array_equal(out[~hole], band[~hole])
    alone = _fill_shifted(band, grain_fill(np.zeros((20, 12), bool), hole, 5.0))
    np.testing.assert_array_equal(alone, band)


def test_match_grain_fills_the_brow_hole_with_the_skins_grain_not_the_frames_hair():
    """The frame: grainy skin with a dark, strongly textured band (brow hair) across it; the puppet
    flat. Without ``fill`` the band stays flat on the puppet (it is not skin); with it the band takes
    the skin's grain, at the skin's amplitude, and none of the hair's darkness."""
    rng = np.random.default_rng(1)
    h, w = 80, 64
    ref = 0.6 + rng.normal(0, 0.02, (h, w, 1)).astype(np.float32) * np.ones(3, np.float32)
    ref[36:44] = 0.2 + rng.normal(0, 0.1, (8, w, 1)).astype(np.float32)  # the hair
    src = np.full((h, w, 3), 0.6, np.float32)
    skin = np.ones((h, w), bool)
    skin[34:46] = False
    hole = ~skin
    plain, _ = match_grain(src, ref, skin)
    out, a = match_grain(src, ref, skin, fill=grain_fill(skin, hole, 12.0))
    assert np.std(plain[38:42, 8:-8] - 0.6) < 1e-3
    inside, outside = np.std(out[38:42, 8:-8] - 0.6), np.std(out[10:30, 8:-8] - 0.6)
    assert 0.6 * outside < inside < 1.5 * outside
    assert abs(float(np.mean(out[36:44] - 0.6))) < 0.005  # no hair


def test_brow_bands_are_either_faces_brows_without_their_eyes_and_lips():
    face68 = simple_face68()
    region = np.ones((256, 256), bool)
    low = face68 + [0, 6]  # the puppet's features lower than the driver's
    m = brow_bands(region, feature_parts(face68, (256, 256)), feature_parts(low, (256, 256)))
    from facetex.geometry.masks import feature_mask
    brows = feature_mask(face68, (256, 256), parts=("brows",)) | feature_mask(low, (256, 256), parts=("brows",))
    assert m.sum() > 0 and not (m & ~brows).any()
    assert not (m & feature_mask(low, (256, 256), parts=("eyes", "lips"))).any()
    assert not brow_bands(np.zeros((256, 256), bool), feature_parts(face68, (256, 256)),
                          feature_parts(low, (256, 256))).any()


def _waves(h=96, w=96, period=7.0, amp=0.05) -> np.ndarray:
    """(h, w, 3) 0.5 + a diagonal sinusoid of ``period`` px: most of its energy in the bands between
    the pixel and a few pixels."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    return (0.5 + amp * np.sin(2 * np.pi * (xx + yy) / period))[..., None] * np.ones(3, np.float32)


def test_match_grain_bands_adds_the_frames_octaves_a_flat_puppet_lacks():
    """A flat puppet lacks every band: each amount is 1 (its variance is the frame's; a sinusoid's
    robust sd is 1.05 x its amplitude, under the clip; its local energy is the skin's median, where
    the texture weight is 1 / (1 + 1/4^4)) and the bands telescope: the result is the puppet plus
    G(0.7) - G(2.8) of the frame (reach 3: the two octaves 0.7-1.4 and 1.4-2.8)."""
    ref = _waves()
    src = np.full_like(ref, 0.5)
    skin = np.ones(ref.shape[:2], bool)
    out, amounts = match_grain_bands(src, ref, skin, reach=3.0)
    assert amounts == (1.0, 1.0)  # 1 / 0.996, capped
    want = src + (cv2.GaussianBlur(ref, (0, 0), 0.7) - cv2.GaussianBlur(ref, (0, 0), 2.8)) / (1 + 4.0 ** -4)
    np.testing.assert_allclose(out[12:-12, 12:-12], want[12:-12, 12:-12], atol=2e-4)
    _, three = match_grain_bands(src, ref, skin, reach=GRAIN_BAND_SIGMAS[3])  # one octave more
    assert len(three) == 3


def test_match_grain_bands_adds_nothing_below_the_reach_or_where_the_puppet_has_the_band():
    ref = _waves()
    skin = np.ones(ref.shape[:2], bool)
    out, amounts = match_grain_bands(np.full_like(ref, 0.5), ref, skin, reach=1.3)  # under one octave
    assert amounts == () and np.all(out == 0.5)
    out, amounts = match_grain_bands(ref, ref, skin, reach=3.0)  # already as detailed
    assert amounts == (0.0, 0.0) and np.array_equal(out, ref)
    half = 0.5 + 0.5 * (ref - 0.5)  # the same wave at half the amplitude: (1/2 + 0.996 a)^2 = 1
    out, amounts = match_grain_bands(half, ref, skin, reach=3.0)
    assert np.allclose(amounts, 0.5 * (1 + 4.0 ** -4), atol=2e-3)
    _, capped = match_grain_bands(np.full_like(ref, 0.5), ref, skin, reach=3.0, max_amount=0.3)
    assert capped == (0.3, 0.3)


def test_match_grain_bands_leave_out_patches_of_strong_structure():
    """A patch of the frame whose band is 4x the skin's amplitude (stubble, a moustache): its local
    energy is 16x the skin's median, the weight 1 / (1 + (16 / kappa^2)^4) = 1/257 inside it."""
    ref = _waves(amp=0.02)
    ref[30:60, 30:60] = 0.5 + 4 * (ref[30:60, 30:60] - 0.5)
    src = np.full_like(ref, 0.5)
    out, amounts = match_grain_bands(src, ref, np.ones(ref.shape[:2], bool), reach=3.0)
    inner = np.s_[38:52, 38:52]
    assert np.abs(out[inner] - 0.5).max() < 2 * 4 * 0.02 / 257 * 1.5  # two bands, each 1/257 of 0.08
    assert np.abs(out[5:20, 70:90] - 0.5).max() > 0.5 * 0.02  # the skin's own texture comes through


def test_match_grain_bands_stay_on_the_skin():
    """Pixels beyond the skin by more than 4 x the coarsest band's finer sigma are untouched."""
    ref = _waves()
    src = np.full_like(ref, 0.5)
    skin = np.zeros(ref.shape[:2], bool)
    skin[:, :40] = True
    out, amounts = match_grain_bands(src, ref, skin, reach=3.0)
    assert min(amounts) > 0
    np.testing.assert_array_equal(out[:, 40 + 4 * 2:], src[:, 40 + 4 * 2:])  # 4 x 1.4 px feather
    assert np.std(out[:, 5:30] - src[:, 5:30]) > 0.01


def _lips68(cx, cy, width=80.0, thick=12.0, gap=10.0):
    """(68, 2) points whose lips 48-67 are a mouth ``width`` px wide at (cx, cy): each lip ``thick``
    px, the inner lips ``gap`` px apart in the middle (the rest of the face far away)."""
    p = np.zeros((68, 2))
    p[:48] = (cx, cy - 3 * width)
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    hw, hh = width / 2, gap / 2 + thick
    p[48:60] = np.c_[cx - hw * np.cos(t), cy - hh * np.sin(t)]  # 48 left corner, 51 top, 57 bottom
    ui = np.array([-0.35, -0.2, 0.0, 0.2, 0.35]) * width
    p[60:65] = np.c_[cx + ui, cy - gap / 2 * np.array([0.3, 1, 1, 1, 0.3])]
    p[65:68] = np.c_[cx + ui[3:0:-1], np.full(3, cy + gap / 2)]
    return p


def _lined_lips(p, shape, stripes=True):
    """Skin 0.75; lips 0.5 with vertical lines 0.5 +- 0.05 every 6 px (when ``stripes``)."""
    h, w = shape
    lips = (polygon_mask(p[48:60], shape) > 0.5) & ~(polygon_mask(p[60:68], shape) > 0.5)
    xx = np.mgrid[0:h, 0:w][1]
    lines = 0.05 * np.sign(np.sin(2 * np.pi * (xx - p[48, 0]) / 6.0)) if stripes else 0.0
    img = np.where(lips, 0.5 + lines, 0.75).astype(np.float32)
    return np.repeat(img[..., None], 3, axis=2), lips


def test_match_lip_detail_moves_the_drivers_lip_lines_onto_the_puppets_lips():
    """The puppet's flat lips sit 20 px right and 8 px lower than the driver's lined lips: its lips
    get the driver's lines where they are on the driver's lips (the band's correlation with the
    driver's lines moved by (20, 8) > 0.8 in the lips' middle), nothing outside its lips, and
    less of it on the lips' edges."""
    shape = (120, 200)
    d = _lips68(80, 60)
    p = d.copy()
    p[48:68] += (20, 8)
    ref, _ = _lined_lips(d, shape)
    src, lips_p = _lined_lips(p, shape, stripes=False)
    out, a = match_lip_detail(src, ref, d, p)
    assert 0.3 < a <= 1.0
    diff = (out - src)[..., 0]
    moved = np.roll(np.roll(ref[..., 0], 8, axis=0), 20, axis=1) - 0.5
    core = cv2.erode(lips_p.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    core[:, :int(p[48, 0]) + 12] = False  # away from the corners
    core[:, int(p[54, 0]) - 12:] = False
    assert core.sum() > 200
    assert np.corrcoef(diff[core], moved[core])[0, 1] > 0.8
    assert np.abs(diff[core]).mean() > 0.3 * a * 0.05
    outside = ~(cv2.dilate(lips_p.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    assert np.abs(diff[outside]).max() == 0
    edge = lips_p & ~(cv2.erode(lips_p.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    assert np.abs(diff[edge]).mean() < 0.8 * np.abs(diff[core]).mean()  # faded in from the edges


def test_match_lip_detail_leaves_detailed_lips_and_bad_points_alone():
    shape = (120, 200)
    d = _lips68(80, 60)
    p = d.copy()
    p[48:68] += (20, 8)
    ref, _ = _lined_lips(d, shape)
    lined, _ = _lined_lips(p, shape)  # the puppet's own lips as lined as the driver's
    out, a = match_lip_detail(lined, ref, d, p)
    assert a == 0.0 and np.array_equal(out, lined)
    flat, _ = _lined_lips(p, shape, stripes=False)
    bad = p.copy()
    bad[50] = np.nan
    for kwargs in ({"puppet68": bad}, {"max_amount": 0.0}, {"driver68": _lips68(80, 60, width=6.0)}):
        args = {"driver68": d, "puppet68": p, **kwargs}
        out, a = match_lip_detail(flat, ref, args.pop("driver68"), args.pop("puppet68"), **args)
        assert a == 0.0 and np.array_equal(out, flat)


def _eyes68(cx, cy, iod=100.0, opening=0.3):
    """68 points with both eyes (36-47) centred iod apart round (cx, cy); eye width 0.3 iod, open by
    ``opening`` x the width; the other points far away at the eyes' centre (unused)."""
    p = np.tile([cx, cy], (68, 1)).astype(np.float64)
    w = 0.3 * iod
    for k, ex in ((36, cx - iod / 2), (42, cx + iod / 2)):
        x = ex + w * np.array([-0.5, -1 / 6, 1 / 6, 0.5, 1 / 6, -1 / 6])
        y = cy + 0.5 * opening * w * np.array([0, -1, -1, 0, 1, 1])
        p[k:k + 6] = np.c_[x, y]
    p[36], p[45] = (cx - iod / 2 - w / 2, cy), (cx + iod / 2 + w / 2, cy)
    return p


def _lashed(p, shape, lashes=True):
    """Grey 0.6 skin; each eye's polygon white 0.9; with ``lashes`` a dark 0.2 line 2 px thick along
    each upper lid (36-37-38-39, 42-43-44-45) and a fainter 0.45 line 4 px above it (a crease)."""
    img = np.full(shape, 0.6, np.float32)
    for k in (36, 42):
        cv2.fillPoly(img, [np.round(p[k:k + 6]).astype(np.int32)], 0.9)
        if lashes:
            upper = np.round(p[k:k + 4]).astype(np.int32)
            cv2.polylines(img, [upper], False, 0.2, 2)
            cv2.polylines(img, [upper - (0, 5)], False, 0.45, 1)
    return np.repeat(img[..., None], 3, axis=2)


def test_eye_affine_maps_corner_to_corner_and_across_by_the_openings():
    """The puppet's eye twice the driver's, 30 px right and 10 px up, opened 0.2 x its width to the
    driver's 0.3: every puppet point lands on the driver's (the corners exactly, the lids by the
    ratio 0.3 / 0.2 across); a shut puppet eye is mapped across by 1 (its width's scale)."""
    d = _eyes68(100, 80, iod=100.0, opening=0.3)[36:42]
    p = _eyes68(0, 0, iod=200.0, opening=0.2)[36:42]
    p += (230.0 - p[[0, 3]].mean(0)[0], 70.0 - p[[0, 3]].mean(0)[1])
    A = _eye_affine(p, d)
    mapped = p @ A[:, :2].T + A[:, 2]
    np.testing.assert_allclose(mapped, d, atol=1e-9)
    shut = p.copy()
    shut[:, 1] = shut[[0, 3], 1].mean()
    B = _eye_affine(shut, d)
    np.testing.assert_allclose(B[:, :2], 0.5 * np.eye(2), atol=1e-12)


def test_match_lid_detail_moves_the_drivers_lash_lines_round_the_puppets_eyes():
    """The driver's lashes and creases (dark lines along its upper lids, on skin with a fine grain of
    sd 0.02) onto a puppet with bare lids 20 px right and 6 px lower: the lines land along the
    puppet's upper lids (where they lie on the driver's, moved by (20, 6); clipped at GRAIN_CLIP
    robust sds of the grain), nothing is added deep inside the puppet's eyeballs nor beyond the
    reach, and the amount stays in (0, 1]."""
    from facetex.puppet.detail import LID_DETAIL_REACH

    shape = (160, 260)
    d = _eyes68(120, 70)
    p = d.copy()
    p[36:48] += (20, 6)
    grain = np.random.default_rng(0).normal(0.0, 0.02, shape).astype(np.float32)[..., None]
    ref, src = _lashed(d, shape) + grain, _lashed(p, shape, lashes=False)
    out, a = match_lid_detail(src, ref, d, p)
    assert 0.0 < a <= 1.0
    diff = (out - src)[..., 0]
    moved = np.roll(np.roll(ref[..., 0] - _lashed(d, shape, lashes=False)[..., 0], 6, axis=0), 20, axis=1)
    lines = moved < -0.1
    assert lines.sum() > 60
    assert diff[lines].mean() < -0.02 * a  # darker along the puppet's lash lines
    eyes = np.zeros(shape, np.uint8)
    for k in (36, 42):
        cv2.fillPoly(eyes, [np.round(p[k:k + 6]).astype(np.int32)], 1)
    deep = cv2.erode(eyes, np.ones((7, 7), np.uint8)) > 0
    assert deep.sum() > 30 and np.abs(diff[deep]).max() == 0.0
    far = cv2.dilate(eyes, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * 40 + 1, 2 * 40 + 1))) == 0
    assert LID_DETAIL_REACH * np.linalg.norm(d[36] - d[45]) < 40 and np.abs(diff[far]).max() == 0.0


def test_match_lid_detail_leaves_lashed_lids_and_bad_points_alone():
    shape = (160, 260)
    d = _eyes68(120, 70)
    p = d.copy()
    p[36:48] += (20, 6)
    ref, lashed = _lashed(d, shape), _lashed(p, shape)
    out, a = match_lid_detail(lashed, ref, d, p)
    assert a == 0.0 and np.array_equal(out, lashed)
    bare = _lashed(p, shape, lashes=False)
    bad = p.copy()
    bad[40] = np.nan
    for dd, pp, amount in ((d, bad, 1.0), (d, p, 0.0)):
        out, a = match_lid_detail(bare, ref, dd, pp, max_amount=amount)
        assert a == 0.0 and np.array_equal(out, bare)
