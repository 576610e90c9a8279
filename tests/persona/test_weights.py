"""Regional expression weights (facetex.persona.weights), on hand-made fiducials."""

import math

import numpy as np
import pytest

from facetex.errors import BadInputError
from facetex.geometry.frontalize import canonical_points68
from facetex.landmarks import POINTS49_INDEX
from facetex.persona.pyramid import _cut_small
from facetex.persona.weights import (
    RIGID49,
    adaptive_sigma,
    face_support,
    fit_expression_model,
    iod49,
    mix_similarities,
    normalised_fiducials,
    region_masks,
)

P68 = canonical_points68((192, 240))
M = P68[POINTS49_INDEX]


def test_normalised_fiducials_remove_similarity_and_scale_by_iod():
    a = math.radians(10)
    R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    moved = 1.3 * M @ R.T + [7.0, -4.0]
    z0, z1 = normalised_fiducials(M, M), normalised_fiducials(moved, M)
    np.testing.assert_allclose(z1, z0, atol=1e-9)  # a similarity of M is M
    np.testing.assert_allclose(z0[RIGID49].mean(axis=0), 0, atol=1e-12)  # origin: rigid centroid
    assert iod49(z0) == pytest.approx(1.0)  # unit: M's eye-centre distance
    # an expression change (mouth points only) survives the normalisation
    smile = M.copy()
    smile[31:49, 1] += 3.0
    assert np.abs(normalised_fiducials(smile, M)[31:49] - z0[31:49]).max() > 0.5 * 3.0 / iod49(M)


def test_adaptive_sigma_hand_computed():
    d = np.array([[4.0, 1.0, 3.0, 2.0], [0.0, 0.0, 5.0, 6.0]])
    np.testing.assert_allclose(adaptive_sigma(d, 2), [1.0, 1e-9])  # 2nd nearest / 2, floored
    np.testing.assert_allclose(adaptive_sigma(d, 3, floor=0.1), [1.5, 2.5])
    np.testing.assert_allclose(adaptive_sigma(d, 99), [2.0, 3.0])  # K capped at n


def test_mouth_similarities_hand_computed():
    # five photos that differ only by point 31 (iBUG 48, a mouth corner) moved right by d_i px;
    # rigid points are identical, so the Procrustes step is the identity. Centring the 18 mouth
    # points moves that point by d (17/18) and the others by -d/18: the mouth distance between
    # photos a and b is |d_a - d_b| sqrt(17/18) / IOD
    d = np.array([0.0, 1.0, 2.0, 4.0, 8.0])
    F = np.repeat(M[None], 5, axis=0)
    F[:, 31, 0] += d
    model = fit_expression_model(F, neighbours=2)
    iod = iod49(F.mean(axis=0))
    target = M.copy()
    target[31, 0] += 1.5
    s = model.similarities(target)  # (3 regions, 5 photos)
    dist = np.abs(d - 1.5) * math.sqrt(17 / 18) / iod
    sigma = np.sort(dist)[1] / 2  # 2nd nearest photo / 2
    np.testing.assert_allclose(s[0], np.exp(-dist**2 / (2 * sigma**2)), rtol=1e-9)
    # the eyes did not change: every photo is as similar as the best
    np.testing.assert_allclose(s[1], 1.0)
    # batched targets give the same numbers
    np.testing.assert_allclose(model.similarities(np.stack([target, target]))[1], s)
    assert model.summary()["mouth"]["neighbours"] == 2
    with pytest.raises(BadInputError):
        fit_expression_model(F[:2])
    with pytest.raises(BadInputError):
        fit_expression_model(F, neighbours=(2, 3))


def test_similarities_of_many_targets_are_computed_in_blocks_with_the_same_values(monkeypatch):
    """A long clip's targets are measured a block at a time (memory), bit for bit as all at once."""
    import facetex.persona.weights as w

    rng = np.random.default_rng(3)
    F = M[None] + rng.normal(0, 1.5, (12, 49, 2))
    model = fit_expression_model(F, neighbours=2)
    targets = M[None] + rng.normal(0, 1.5, (10, 49, 2))
    monkeypatch.setattr(w, "DISTANCE_BLOCK", 10**6)
    whole = model.evaluate(targets), model.sigmas(targets)
    monkeypatch.setattr(w, "DISTANCE_BLOCK", 3)  # blocks 3 + 3 + 3 + 1
    blocks = model.evaluate(targets), model.sigmas(targets)
    for a, b in zip((whole[0][1], whole[0][2], whole[1]), (blocks[0][1], blocks[0][2], blocks[1])):
        np.testing.assert_array_equal(a, b)
    assert whole[0][2].shape == (10, 3, 12)


def test_mix_similarities_hand_computed():
    S = np.array([[1.0, 1.0, 2.0],  # mouth: total 4
                  [3.0, 0.0, 1.0],  # eyes: normalised (0.75, 0, 0.25)
                  [0.0, 2.0, 2.0]])  # face: normalised (0, 0.5, 0.5)
    mix = (("mouth", (("mouth", 0.5), ("face", 0.25), ("eyes", 0.25))),)
    out = mix_similarities(S, ("mouth", "eyes", "face"), mix)
    # 0.5 (0.25, 0.25, 0.5) + 0.25 (0, 0.5, 0.5) + 0.25 (0.75, 0, 0.25), times the mouth's total 4
    np.testing.assert_allclose(out[0], 4 * np.array([0.3125, 0.25, 0.4375]))
    np.testing.assert_array_equal(out[1:], S[1:])  # the other regions as they were
    np.testing.assert_allclose(out[0].sum(), S[0].sum())  # Eq. 3's balance with the uniform term kept
    # batched (B, R, n) as one at a time; no mix: unchanged
    np.testing.assert_allclose(mix_similarities(np.stack([S, 2 * S]), ("mouth", "eyes", "face"), mix)[1], 2 * out)
    np.testing.assert_array_equal(mix_similarities(S, ("mouth", "eyes", "face"), ()), S)
    with pytest.raises(BadInputError, match="nose"):
        mix_similarities(S, ("mouth", "eyes", "face"), (("mouth", (("nose", 1.0),)),))


def test_expression_model_mixes_the_mouth_and_checks_the_shares():
    rng = np.random.default_rng(5)
    F = M[None] + rng.normal(0, 1.5, (9, 49, 2))
    t = M + rng.normal(0, 1.5, (49, 2))
    plain = fit_expression_model(F, neighbours=2).similarities(t)
    mixed = fit_expression_model(F, neighbours=2, mix=(("mouth", (("mouth", 0.4), ("face", 0.6))),)).similarities(t)
    want = (0.4 * plain[0] / plain[0].sum() + 0.6 * plain[2] / plain[2].sum()) * plain[0].sum()
    np.testing.assert_allclose(mixed[0], want, rtol=1e-12)
    np.testing.assert_array_equal(mixed[1:], plain[1:])
    for bad in ((("mouth", (("mouth", 0.4), ("face", 0.4))),),  # shares sum to 0.8
                (("mouth", (("mouth", 1.5), ("face", -0.5))),),  # a negative share
                (("mouth", (("teeth", 1.0),)),)):  # not a region
        with pytest.raises(BadInputError):
            fit_expression_model(F, neighbours=2, mix=bad)


def test_texture_params_mix_the_mouth_only_when_its_sources_are_regions():
    from facetex.persona import TextureParams

    assert TextureParams().region_mix() == (("mouth", (("mouth", 0.4), ("face", 0.4), ("eyes", 0.2))),)
    assert TextureParams(mouth_mix=()).region_mix() == ()
    assert TextureParams(regions=("mouth", "face")).region_mix() == ()  # the eyes are no weight region


def test_region_masks_partition_and_feather():
    m = region_masks(P68, (240, 192))
    assert m.shape == (3, 240, 192) and m.min() >= 0
    np.testing.assert_allclose(m.sum(axis=0), 1.0, atol=1e-6)
    mouth_c = np.round((P68[48] + P68[54]) / 2).astype(int)
    eye_c = np.round(P68[36:42].mean(axis=0)).astype(int)
    assert m[0, mouth_c[1], mouth_c[0]] > 0.99 and m[1, mouth_c[1], mouth_c[0]] < 0.01
    assert m[1, eye_c[1], eye_c[0]] > 0.97 and m[0, eye_c[1], eye_c[0]] < 0.01
    assert m[2, 5, 5] > 0.99  # far from both: the rest of the face
    # feathered: no jump between neighbouring pixels larger than a Gaussian edge of 0.12 IOD allows
    assert max(np.abs(np.diff(m, axis=1)).max(), np.abs(np.diff(m, axis=2)).max()) < 0.1
    sup = face_support(P68, (240, 192))
    assert sup[mouth_c[1], mouth_c[0]] > 0.99 and sup[2, 2] < 0.01


def test_cut_small_hand_computed():
    S = np.array([[0.5, 0.05, 0.3, 0.15]])
    # mass 0.9: the smallest weights holding < 10 % of the total go (0.05; 0.05 + 0.15 = 0.2 stays)
    np.testing.assert_allclose(_cut_small(S, 0.9), [[0.5, 0.0, 0.3, 0.15]])
    np.testing.assert_allclose(_cut_small(S, 0.9, max_photos=2), [[0.5, 0.0, 0.3, 0.0]])
    np.testing.assert_allclose(_cut_small(S, 1.0), S)


# ------------------------------------------------------------------ temporal coherence
def _still_coords(N, value=0.0):
    return [np.full((N, 4), value)]


def test_temporal_weights_hand_computed_three_frames():
    """sigma_frames = 1, one region, equal expressions: frame t's normalised weights become the
    Gaussian-in-time average exp(-o^2/2) over frames t+o (|o| <= 3), times frame t's own total."""
    from facetex.persona.weights import temporal_weights

    W = np.array([[[2.0, 0.0]], [[0.0, 1.0]], [[1.0, 1.0]]])  # (N=3, R=1, n=2), totals 2, 1, 2
    P = np.array([[1.0, 0.0], [0.0, 1.0], [0.5, 0.5]])
    e1, e2 = math.exp(-0.5), math.exp(-2.0)
    k = np.array([[1, e1, e2], [e1, 1, e1], [e2, e1, 1]])
    want = (k @ P) / k.sum(axis=1, keepdims=True) * np.array([2.0, 1.0, 2.0])[:, None]
    out = temporal_weights(W, _still_coords(3), np.ones((3, 1)), sigma_frames=1.0)
    np.testing.assert_allclose(out[:, 0], want, rtol=1e-12)
    np.testing.assert_allclose(out.sum(axis=-1), W.sum(axis=-1), rtol=1e-12)  # totals kept


def test_temporal_weights_do_not_mix_shots():
    """Frames 0-1 and 2-3 are two shots: each frame averages only its own shot's weights."""
    from facetex.persona.weights import temporal_weights

    W = np.array([[[1.0, 0.0]], [[1.0, 0.0]], [[0.0, 1.0]], [[0.0, 1.0]]])
    mixed = temporal_weights(W, _still_coords(4), np.ones((4, 1)), sigma_frames=1.0)
    assert mixed[1, 0, 1] > 0.2  # across the cut: the next shot's photo
    out = temporal_weights(W, _still_coords(4), np.ones((4, 1)), sigma_frames=1.0, segments=[0, 0, 1, 1])
    np.testing.assert_allclose(out, W, atol=1e-12)


def test_temporal_weights_last_frame_only_is_the_last_row():
    """``last=True`` (the live session's causal filter) gives exactly the full result's last row."""
    from facetex.persona.weights import temporal_weights

    rng = np.random.default_rng(3)
    for N in (1, 2, 7, 12):
        W = rng.random((N, 2, 9))
        coords = [rng.random((N, 6)), rng.random((N, 4))]
        sig = rng.random((N, 2)) + 0.1
        full = temporal_weights(W, coords, sig, sigma_frames=2.0, range_scale=1.0)
        last = temporal_weights(W, coords, sig, sigma_frames=2.0, range_scale=1.0, last=True)
        assert last.shape == (1, 2, 9)
        np.testing.assert_array_equal(last[0], full[-1])


def test_temporal_weights_still_sequence_gets_constant_weights():
    """A still face whose nearest photos swap with landmark jitter (photo 0 or 1 alternately)
    gets one blend: interior frames all ~[0.5, 0.5] x their total; a still face that already
    picks the same photos is left exactly as it is."""
    from facetex.persona.weights import temporal_weights

    N = 40
    W = np.zeros((N, 1, 3))
    W[0::2, 0, 0] = 1.0
    W[1::2, 0, 1] = 1.0
    out = temporal_weights(W, _still_coords(N), np.ones((N, 1)), sigma_frames=3.0)
    mid = out[10:-10, 0]
    np.testing.assert_allclose(mid[:, :2], 0.5, atol=2e-3)
    assert np.abs(np.diff(mid, axis=0)).max() < 3e-3  # per-frame swaps of 1.0 before
    assert np.all(mid[:, 2] == 0)  # no photo appears that no frame had
    same = np.repeat(np.array([[[0.2, 0.7, 0.1], [0.0, 0.5, 0.5]]]), N, axis=0) * np.linspace(1, 2, N)[:, None, None]
    out2 = temporal_weights(same, _still_coords(N) * 2, np.ones((N, 2)), sigma_frames=3.0)
    np.testing.assert_allclose(out2, same, rtol=1e-12)


def test_temporal_weights_keep_a_frame_far_in_expression():
    """A frame whose region coordinates are far (many sigmas) from its neighbours' (a mouth
    opening) keeps its own weights, and is not mixed into theirs; another region where it is
    still is smoothed as usual."""
    from facetex.persona.weights import temporal_weights

    N = 9
    W = np.zeros((N, 2, 3))
    W[:, :, 0] = 1.0
    W[4, :, :] = [0.0, 0.0, 3.0]  # frame 4: photo 2 only (in both regions)
    mouth = np.zeros((N, 4))
    mouth[4] = 10.0  # 20 sigmas away in the mouth region
    coords = [mouth, np.zeros((N, 4))]
    out = temporal_weights(W, coords, np.full((N, 2), 1.0), sigma_frames=1.5)
    np.testing.assert_allclose(out[4, 0], [0, 0, 3.0], atol=1e-12)  # mouth: its own weights
    assert np.all(out[[3, 5], 0, 2] < 1e-12)  # neighbours' mouth: not mixed with frame 4
    assert out[3, 1, 2] > 0.05 and out[4, 1, 0] > 0.5  # the still region: smoothed
    np.testing.assert_allclose(out.sum(axis=-1), W.sum(axis=-1), rtol=1e-12)


def test_temporal_weights_off_and_bad_input():
    from facetex.persona.weights import temporal_weights

    W = np.random.default_rng(0).random((5, 2, 4))
    c = _still_coords(5) * 2
    np.testing.assert_array_equal(temporal_weights(W, c, np.ones((5, 2)), sigma_frames=0.0), W)
    with pytest.raises(BadInputError):
        temporal_weights(W[0], c, np.ones((5, 2)), sigma_frames=1.0)
    with pytest.raises(BadInputError):
        temporal_weights(W, c[:1], np.ones((5, 2)), sigma_frames=1.0)


def test_detail_weights_hand_computed():
    from facetex.persona.weights import detail_weights

    W = np.array([[1.0, 0.5, 0.0], [0.2, 0.4, 0.4]])
    # power 2: [1, .25, 0] rescaled to the total 1.5; [.25, 1, 1] rescaled to 1.0
    np.testing.assert_allclose(detail_weights(W, 2.0), [[1.2, 0.3, 0.0], [1 / 9, 4 / 9, 4 / 9]])
    # quality multiplies after the power: [1, .25 * 2, 0] -> total 1.5
    np.testing.assert_allclose(detail_weights(W[:1], 2.0, quality=[1.0, 2.0, 5.0]), [[1.0, 0.5, 0.0]])
    np.testing.assert_array_equal(detail_weights(W, 1.0), W)
    assert detail_weights(np.zeros((1, 3)), 4.0).sum() == 0  # no weight stays none (no NaN)
    with pytest.raises(BadInputError, match="detail power"):
        detail_weights(W, 0.0)
