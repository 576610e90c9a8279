import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from facetex.errors import BadInputError
from facetex.transfer.losses import (
    MRFLoss, content_loss, extract_patches, gram_loss, gram_matrix, mrf_loss, mrf_match, mrf_memory_estimate,
    structure_loss, style_patches, tv_loss,
)

D64 = torch.float64


def _brute_force(t, s, size=3, style_stride=2, target_stride=1):
    """Eq. 1 by the definition: the full NCC matrix, then Eq. 2."""
    c = t.shape[0]
    tp = extract_patches(t, size, target_stride).reshape(-1, c * size * size)
    sp = extract_patches(s, size, style_stride).reshape(-1, c * size * size)
    ncc = (tp @ sp.T) / tp.norm(dim=1)[:, None] / sp.norm(dim=1)[None]
    nn = ncc.argmax(1)
    return nn, (tp - sp[nn]).square().sum()


# ---------------------------------------------------------------- patches
def test_extract_patches_grid_includes_last_origin():
    f = torch.arange(36.0).reshape(1, 6, 6)
    p = extract_patches(f, 3, 2)  # origins 0, 2 and the last one, 3
    assert p.shape == (9, 1, 3, 3)
    assert torch.equal(p[0, 0], f[0, 0:3, 0:3])
    assert torch.equal(p[1, 0], f[0, 0:3, 2:5])
    assert torch.equal(p[2, 0], f[0, 0:3, 3:6])
    assert torch.equal(p[8, 0], f[0, 3:6, 3:6])
    assert extract_patches(f[None], 3, 1).shape == (16, 1, 3, 3)
    assert extract_patches(torch.zeros(2, 5, 5), 3, 2).shape == (4, 2, 3, 3)  # 0, 2 (2 is last)


def test_extract_patches_rejects_too_small_maps():
    with pytest.raises(BadInputError):
        extract_patches(torch.zeros(1, 2, 5), 3)


# ---------------------------------------------------------------- MRF, hand-computed
def _stripes():
    # Style: one channel, 3 × 5, a single bright column at x=2. Its three 3×3 patches (stride 1)
    # have the bright column at x = 2, 1, 0 respectively.
    s = torch.zeros(1, 3, 5, dtype=D64)
    s[0, :, 2] = 1.0
    return s


def test_mrf_hand_case_best_match_and_loss():
    s = _stripes()
    t = torch.zeros(1, 3, 3, dtype=D64)
    t[0, :, 1] = 2.0  # bright middle column: NCC 1 with style patch 1 (scale does not matter)
    idx, ncc = mrf_match(t, s, style_stride=1, return_ncc=True)
    assert idx.tolist() == [[1]] and ncc.item() == pytest.approx(1.0)
    assert mrf_loss(t, s, style_stride=1).item() == pytest.approx(3 * (2 - 1) ** 2)
    t2 = torch.zeros(1, 3, 3, dtype=D64)
    t2[0, :, 0] = 3.0  # bright left column: style patch 2
    assert mrf_match(t2, s, style_stride=1).tolist() == [[2]]
    assert mrf_loss(t2, s, style_stride=1).item() == pytest.approx(3 * (3 - 1) ** 2)


def test_mrf_hand_case_gradients_paper_and_reference():
    s = _stripes()
    t = torch.zeros(1, 3, 3, dtype=D64)
    t[0, :, 1] = 2.0
    t.requires_grad_(True)
    mrf_loss(t, s, style_stride=1).backward()
    expected = torch.zeros(1, 3, 3, dtype=D64)
    expected[0, :, 1] = 2 * (2 - 1)  # d/dx (x - 1)^2
    assert torch.allclose(t.grad, expected)
    t.grad = None
    ref = mrf_loss(t, s, style_stride=1, variant="reference")
    assert ref.item() == pytest.approx(0.5 * 3)  # one patch, coverage 1: half the sum
    ref.backward()
    assert torch.allclose(t.grad, expected / 2)  # CNNMRF: strength * (x - S), no factor 2


def test_mrf_matches_are_recomputed_every_call():
    s = style_patches(_stripes(), 3, 1)
    t = torch.zeros(1, 3, 3, dtype=D64)
    t[0, :, 1] = 1.0
    assert mrf_loss(t, s).item() == pytest.approx(0.0)
    t = torch.zeros(1, 3, 3, dtype=D64)
    t[0, :, 2] = 1.0  # now style patch 0 is the best one; loss stays 0 only if rematched
    assert mrf_loss(t, s).item() == pytest.approx(0.0)


# ---------------------------------------------------------------- MRF vs brute force
@pytest.mark.parametrize("shape_t,shape_s,ss,ts", [((4, 9, 11), (4, 10, 8), 2, 1), ((3, 7, 7), (3, 12, 9), 1, 2),
                                                   ((6, 5, 13), (6, 8, 8), 2, 2)])
def test_mrf_argmax_equals_brute_force(shape_t, shape_s, ss, ts):
    g = torch.Generator().manual_seed(sum(shape_t))
    t, s = torch.randn(*shape_t, generator=g, dtype=D64), torch.randn(*shape_s, generator=g, dtype=D64)
    nn, loss = _brute_force(t, s, 3, ss, ts)
    idx = mrf_match(t, s, style_stride=ss, target_stride=ts)
    assert torch.equal(idx.reshape(-1), nn)
    assert mrf_loss(t, s, style_stride=ss, target_stride=ts).item() == pytest.approx(loss.item(), rel=1e-10)


def test_mrf_module_equals_function():
    g = torch.Generator().manual_seed(6)
    t, s = torch.rand(4, 9, 9, generator=g), torch.rand(4, 10, 10, generator=g)
    assert MRFLoss(s, variant="reference")(t).item() == mrf_loss(t, s, variant="reference").item()


def test_mrf_chunked_equals_unchunked():
    g = torch.Generator().manual_seed(1)
    t, s = torch.rand(8, 20, 17, generator=g), torch.rand(8, 23, 19, generator=g)
    base_idx = mrf_match(t, s, chunk=10**6)
    base = mrf_loss(t, s, chunk=10**6)
    for chunk in (1, 7, 64):
        assert torch.equal(mrf_match(t, s, chunk=chunk), base_idx)
        assert mrf_loss(t, s, chunk=chunk).item() == pytest.approx(base.item(), rel=1e-6)


def test_mrf_gradient_flows_only_to_target_and_equals_brute_force():
    g = torch.Generator().manual_seed(2)
    t = torch.randn(5, 9, 10, generator=g, dtype=D64, requires_grad=True)
    s = torch.randn(5, 11, 9, generator=g, dtype=D64, requires_grad=True)
    (gt,) = torch.autograd.grad(_brute_force(t, s.detach())[1], t)
    loss = mrf_loss(t, s)
    loss.backward()
    assert torch.allclose(t.grad, gt, atol=1e-10)
    assert s.grad is None
    # mean reduction divides by the number of target patches
    assert mrf_loss(t, s, reduction="mean").item() == pytest.approx(loss.item() / (7 * 8))


def test_mrf_target_weight_equals_brute_force_weighted_sum():
    """Σ_i Σ_{p∈i} w(p)·‖x(p) − S_nn(i)(p)‖², and patches with no weight are not matched."""
    g = torch.Generator().manual_seed(5)
    t = torch.randn(4, 9, 11, generator=g, dtype=D64)
    s = torch.randn(4, 10, 9, generator=g, dtype=D64)
    w = torch.zeros(9, 11, dtype=D64)
    w[2:6, 3:9] = torch.rand(4, 6, generator=g, dtype=D64) + 0.1
    nn, _ = _brute_force(t, s)
    k = 3
    sp = extract_patches(s, k, 2)
    tp = extract_patches(t, k, 1)
    wp = extract_patches(w[None], k, 1)[:, 0]  # (N_t, k, k) weights under each target patch
    want = ((tp - sp[nn]).square().sum(1) * wp).sum()
    assert mrf_loss(t, s, target_weight=w).item() == pytest.approx(want.item(), rel=1e-10)
    assert mrf_loss(t, s, target_weight=torch.ones(9, 11, dtype=D64)).item() == pytest.approx(
        mrf_loss(t, s).item(), rel=1e-12)
    tt = t.clone().requires_grad_(True)
    mrf_loss(tt, s, target_weight=w).backward()
    assert tt.grad[:, w == 0].abs().max() == 0 and tt.grad[:, w > 0].abs().max() > 0
    with pytest.raises(BadInputError):
        mrf_loss(t, s, target_weight=torch.ones(5, 5, dtype=D64))


def test_mrf_reference_is_coverage_weighted_half_sum():
    g = torch.Generator().manual_seed(3)
    t, s = torch.randn(3, 8, 9, generator=g, dtype=D64).relu(), torch.randn(3, 9, 9, generator=g, dtype=D64).relu()
    idx = mrf_match(t, s, target_stride=2).reshape(-1)
    sp = extract_patches(s, 3, 2)
    ys, xs = [0, 2, 4, 5], [0, 2, 4, 6]  # stride-2 origins plus the last one
    diff = torch.zeros_like(t)
    count = torch.zeros(8, 9, dtype=D64)
    for n, (y, x) in enumerate((y, x) for y in ys for x in xs):
        diff[:, y:y + 3, x:x + 3] += (t[:, y:y + 3, x:x + 3] - sp[idx[n]]).square()
        count[y:y + 3, x:x + 3] += 1
    expected = 0.5 * (diff / count).sum()
    assert mrf_loss(t, s, variant="reference").item() == pytest.approx(expected.item(), rel=1e-10)


def test_mrf_reference_threshold_drops_undefined_matches():
    s = _stripes()
    t = torch.zeros(1, 3, 3, dtype=D64)  # an all-zero patch has no NCC: the code drops it
    assert mrf_loss(t, s, style_stride=1, variant="reference").item() == 0.0
    assert mrf_loss(t, s, style_stride=1).item() == pytest.approx(3.0)  # paper keeps it


@pytest.mark.parametrize("variant", ["paper", "reference"])
def test_mrf_gradcheck_fixed_matches(variant):
    g = torch.Generator().manual_seed(4)
    t = torch.rand(2, 6, 7, generator=g, dtype=D64, requires_grad=True)
    s = torch.rand(2, 7, 7, generator=g, dtype=D64)
    stride = 1 if variant == "paper" else 2
    m = mrf_match(t, s, target_stride=stride)
    assert torch.autograd.gradcheck(lambda x: mrf_loss(x, s, variant=variant, matches=m), (t,))


def test_mrf_rejects_bad_input():
    with pytest.raises(BadInputError):
        mrf_loss(torch.zeros(2, 5, 5), torch.zeros(3, 5, 5))
    with pytest.raises(BadInputError):
        mrf_loss(torch.zeros(2, 5, 5), torch.zeros(2, 5, 5), variant="nope")


def test_mrf_memory_bound_at_1000px_equivalent():
    # Memory is O(N_s·C·k² + C·H·W), never O(N_t·N_s). At relu4_1 of a 1000 px image (125²)
    # the NCC matrix, 123² × 62² floats, is itself only a few feature maps; at relu3_1 (250²,
    # 256 ch) it would be 3.6 GB and the estimate of all mrf_loss allocates is a small part.
    full = 123 * 123 * 62 * 62 * 4
    assert mrf_memory_estimate(256, (125, 125), (125, 125)) < full
    assert mrf_memory_estimate(256, (250, 250), (250, 250)) < 248 * 248 * 125 * 125 * 4 / 6


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc")
def test_mrf_measured_peak_memory_stays_below_full_matrix():
    # Peak RSS (VmHWM) growth of matching + loss + backward at 125² vs 125² (stride 2), in a
    # fresh process: torch's allocator is invisible to tracemalloc, and ru_maxrss survives exec
    # (it would report pytest's peak). Few channels keep it fast; the N_t × N_s matrix does
    # not depend on C.
    code = textwrap.dedent("""
        import torch
        from facetex.transfer.losses import mrf_loss, mrf_memory_estimate
        from facetex._memory import peak_rss, reset_peak_rss
        torch.manual_seed(0)
        t = torch.rand(1, 8, 125, 125, requires_grad=True); s = torch.rand(1, 8, 125, 125)
        mrf_loss(t[..., :8, :8], s[..., :8, :8]).backward()  # warm up allocator and kernels
        t.grad = None
        base = reset_peak_rss()
        mrf_loss(t, s).backward()
        print(peak_rss() - base, mrf_memory_estimate(8, (125, 125), (125, 125)))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    grown, estimate = map(int, out.stdout.split())
    full = 123 * 123 * 62 * 62 * 4
    # the stride-1 one-piece matching (unfold, 16 MiB score blocks, fold) peaks at ~0.37 of the
    # full matrix at this small size (0.33-0.37 over reruns): never the matrix itself
    assert grown < full / 2
    assert grown <= estimate + 16 * 2**20


# ---------------------------------------------------------------- other losses
def test_content_loss_hand_case():
    a, b = torch.tensor([[1.0, 2.0]]), torch.zeros(1, 2)
    assert content_loss(a, b).item() == 5.0
    assert content_loss(a, b, reduction="mean").item() == 2.5
    with pytest.raises(BadInputError):
        content_loss(a, torch.zeros(2, 1))


def test_gram_matrix_and_loss_hand_case():
    f = torch.tensor([[[1.0, 2.0]], [[3.0, 4.0]]])  # C=2, H=1, W=2
    g = gram_matrix(f, normalize=False)
    assert g.tolist() == [[5.0, 11.0], [11.0, 25.0]]
    assert torch.allclose(gram_matrix(f), g / 4)  # / (C·H·W)
    assert gram_matrix(f[None]).shape == (1, 2, 2)
    expected = (25 + 121 + 121 + 625) / 16
    assert gram_loss(f, torch.zeros_like(f)).item() == pytest.approx(expected)
    assert gram_loss(f, torch.zeros(2, 2)).item() == pytest.approx(expected)  # precomputed Gram
    assert gram_loss(f, torch.zeros_like(f), reduction="mean").item() == pytest.approx(expected / 4)


def test_structure_loss_hand_case():
    t = {"a": torch.ones(1, 1, 1, 2), "b": torch.tensor([2.0, 0.0]).reshape(1, 2, 1, 1)}
    c = {"a": torch.zeros(1, 1, 1, 2), "b": torch.zeros(1, 2, 1, 1), "unused": torch.zeros(3)}
    # Eq. 3: 2/(1·1·2) + 4/(2·1·1)
    assert structure_loss(t, c).item() == pytest.approx(1.0 + 2.0)
    with pytest.raises(BadInputError):
        structure_loss({"x": torch.zeros(1)}, {})


def test_tv_loss_hand_case():
    x = torch.tensor([[0.0, 1.0], [3.0, 5.0]])[None, None]
    assert tv_loss(x).item() == (1 + 4) + (9 + 16)
    assert tv_loss(x, variant="reference").item() == 0.5 * (1 + 9)  # top-left crop only
    assert tv_loss(torch.ones(3, 4, 4)).item() == 0.0


def test_losses_gradcheck_float64():
    g = torch.Generator().manual_seed(5)
    x = torch.rand(1, 2, 4, 5, generator=g, dtype=D64, requires_grad=True)
    y = torch.rand(1, 2, 4, 5, generator=g, dtype=D64)
    assert torch.autograd.gradcheck(lambda v: tv_loss(v), (x,))
    assert torch.autograd.gradcheck(lambda v: tv_loss(v, "reference"), (x,))
    assert torch.autograd.gradcheck(lambda v: content_loss(v, y), (x,))
    assert torch.autograd.gradcheck(lambda v: gram_loss(v, y), (x,))
    assert torch.autograd.gradcheck(lambda v: structure_loss({"a": v, "b": v * v}, {"a": y, "b": y}), (x,))


def test_channel_softmax_hand_case_and_gradcheck():
    from facetex.transfer.losses import channel_softmax

    f = torch.tensor([[[0.0]], [[1.0]], [[2.0]]], dtype=D64)  # (3, 1, 1)
    e = torch.exp(torch.tensor([0.0, 1.0, 2.0], dtype=D64))
    assert torch.allclose(channel_softmax(f)[:, 0, 0], e / e.sum())
    assert torch.allclose(channel_softmax(f, 2.0)[:, 0, 0], torch.exp(torch.tensor([0.0, .5, 1.0], dtype=D64)) /
                          torch.exp(torch.tensor([0.0, .5, 1.0], dtype=D64)).sum())
    x = torch.randn(1, 4, 3, 3, dtype=D64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: channel_softmax(t, 0.7), (x,))
    with pytest.raises(BadInputError):
        channel_softmax(torch.zeros(3, 3))


# ---------------------------------------------------------------- MRF, one-piece (unfold/fold) path
@pytest.mark.parametrize("variant", ["paper", "reference"])
@pytest.mark.parametrize("weighted", [False, True])
def test_mrf_one_piece_path_equals_the_blockwise_path(monkeypatch, variant, weighted):
    import facetex.transfer.losses as losses

    g = torch.Generator().manual_seed(3)
    t = torch.rand(6, 17, 13, generator=g)
    t[:, :4, :4] = 0.0  # all-zero target patches: NaN NCC, dropped by the reference threshold
    s = style_patches(torch.rand(6, 15, 11, generator=g), 3, 2)
    tw = (torch.rand(17, 13, generator=g) > 0.6).float() if weighted else None
    out = {}
    for dense in (0, losses._DENSE_ELEMENTS):
        monkeypatch.setattr(losses, "_DENSE_ELEMENTS", dense)
        x = t.clone().requires_grad_(True)
        loss = mrf_loss(x, s, variant=variant, target_weight=tw, reduction="mean")
        loss.backward()
        out[dense] = (loss.detach(), x.grad)
    (v0, g0), (v1, g1) = out.values()
    assert v0 > 0 and g0.abs().max() > 0
    assert torch.allclose(v0, v1, rtol=1e-5) and torch.allclose(g0, g1, rtol=1e-5, atol=1e-7)
    if weighted:  # no gradient where no weighted position is covered
        cover = torch.nn.functional.max_pool2d(tw[None, None], 3, 1, padding=1)[0, 0] > 0
        assert g1[:, ~cover].abs().max() == 0
