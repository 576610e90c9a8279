import numpy as np
import pytest
import torch
import torch.nn.functional as F

from facetex.errors import BadInputError
from facetex.transfer.losses import content_loss, mrf_loss, style_patches, tv_loss
from facetex.transfer.optimize import level_shapes, optimize_image, to_tensor


def _target(h=16, w=16):
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    return np.stack([xx, yy, 0.5 * (xx + yy)], axis=-1).astype(np.float32)


def _l2_tv_builder(target, seen=None):
    def build(level, scale, shape):
        if seen is not None:
            seen.append((level, scale, shape))
        t = F.interpolate(to_tensor(target), size=shape, mode="bilinear", align_corners=False)
        return lambda x: {"l2": content_loss(x, t), "tv": 1e-3 * tv_loss(x)}
    return build


def test_level_shapes():
    assert level_shapes((16, 16)) == [(0.25, (4, 4)), (0.5, (8, 8)), (1.0, (16, 16))]
    assert [s for _, s in level_shapes((15, 17), 3)] == [(4, 5), (8, 9), (15, 17)]  # ceil, as CNNMRF
    assert level_shapes((10, 10), 1) == [(1.0, (10, 10))]


@pytest.mark.parametrize("line_search", ["strong_wolfe", None])
def test_converges_on_l2_plus_tv(line_search):
    target = _target()
    init = np.full_like(target, 0.5)
    seen, calls = [], []
    out, info = optimize_image(init, _l2_tv_builder(target, seen), iters=(20, 20, 20), line_search=line_search,
                               progress=lambda n, **kw: calls.append((n, kw)))
    assert out.shape == target.shape and out.dtype == np.float32
    assert [s[2] for s in seen] == [(4, 4), (8, 8), (16, 16)]
    assert [lv["shape"] for lv in info["levels"]] == [(4, 4), (8, 8), (16, 16)]
    start = content_loss(torch.from_numpy(init), torch.from_numpy(target)).item()
    assert info["levels"][-1]["loss"] < 0.01 * start
    assert np.abs(out - target).max() < 0.05
    assert len(calls) == sum(lv["evaluations"] for lv in info["levels"]) == len(info["loss_history"])
    assert set(info["levels"][0]["loss_terms"]) == {"l2", "tv"}
    assert all(lv["seconds"] > 0 for lv in info["levels"])


def test_deterministic_bitwise():
    target = _target(12, 10)
    init = np.random.default_rng(0).random((12, 10, 3)).astype(np.float32)
    a, ia = optimize_image(init, _l2_tv_builder(target), levels=2, iters=8, seed=3)
    b, ib = optimize_image(init, _l2_tv_builder(target), levels=2, iters=8, seed=3)
    assert np.array_equal(a, b) and ia["loss_history"] == ib["loss_history"]


def test_clamp_and_callback():
    target = _target() * 3 - 1  # out of range: the optimum is clipped to [0, 1]
    got = []
    out, _ = optimize_image(_target(), _l2_tv_builder(target), levels=2, iters=5, save_every=2,
                            callback=lambda image, level, evaluation: got.append((level, image.shape)))
    assert out.min() >= 0 and out.max() <= 1
    assert (0, (8, 8, 3)) in got and got[-1] == (1, (16, 16, 3))
    out2, _ = optimize_image(_target(), _l2_tv_builder(target), levels=1, iters=5, clamp=False)
    assert out2.min() < 0


def test_mrf_with_tiny_random_feature_net_decreases_loss():
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Conv2d(3, 8, 3, padding=1), torch.nn.ReLU(),
                              torch.nn.Conv2d(8, 8, 3, stride=2, padding=1), torch.nn.ReLU()).requires_grad_(False)
    style = np.random.default_rng(1).random((32, 32, 3)).astype(np.float32)

    def build(level, scale, shape):
        s = F.interpolate(to_tensor(style), size=shape, mode="bilinear", align_corners=False, antialias=True)
        sp = style_patches(net(s))
        return lambda x: {"mrf": mrf_loss(net(x), sp), "tv": 1e-2 * tv_loss(x)}

    out, info = optimize_image(_target(32, 32), build, levels=2, iters=(10, 10))
    first = info["loss_history"][len(info["loss_history"]) - info["levels"][-1]["evaluations"]]
    assert info["levels"][-1]["loss"] < first
    assert out.shape == (32, 32, 3)
    again, _ = optimize_image(_target(32, 32), build, levels=2, iters=(10, 10))
    assert np.array_equal(out, again)  # matching, scatter and L-BFGS are deterministic on CPU


def test_bad_arguments():
    with pytest.raises(BadInputError):
        optimize_image(np.zeros((4, 4)), _l2_tv_builder(_target()))
    with pytest.raises(BadInputError):
        optimize_image(_target(), _l2_tv_builder(_target()), levels=3, iters=(1, 2))
    with pytest.raises(BadInputError):
        optimize_image(_target(), _l2_tv_builder(_target()), optimizer="sgd")


def test_level_init_residual_keeps_init_detail():
    init = np.random.default_rng(2).random((16, 16, 3)).astype(np.float32)

    def build(level, scale, shape):
        return lambda x: {"zero": 0.0 * x.sum()}  # nothing changes the image

    up, _ = optimize_image(init, build, levels=2, iters=2, level_init="upsample")
    res, info = optimize_image(init, build, levels=2, iters=2, level_init="residual")
    assert np.allclose(res, init, atol=1e-6)  # init + upsampled (zero) change
    assert not np.allclose(up, init, atol=1e-2)  # the half-size image, upsampled: blurred
    assert info["level_init"] == "residual"


def test_convergence_test_ends_a_level_whose_loss_stopped_falling():
    # an ill-conditioned quadratic (weights 1e-6..1): L-BFGS keeps lowering it by tiny amounts
    target = _target()
    w = torch.logspace(-6, 0, target.size).reshape(1, 3, *target.shape[:2])
    t = to_tensor(target)

    def build(level, scale, shape):
        return lambda x: {"q": (w * (x - t) ** 2).sum()}

    init = np.zeros_like(target)
    out, info = optimize_image(init, build, levels=1, iters=400, converge=(10, 0.1), clamp=False)
    lv = info["levels"][0]
    assert lv["stop"] == "converged: < 0.1 in 10 iterations"
    assert 20 <= lv["iterations"] < 400 and lv["iterations"] % 10 == 0
    h = info["loss_history"]
    assert min(h) < 0.01 * h[0]
    # the same level without the test runs longer
    _, full = optimize_image(init, build, levels=1, iters=400, clamp=False)
    assert full["levels"][0]["iterations"] > lv["iterations"]


def test_convergence_checks_keep_the_lbfgs_history():
    """Chunks of one L-BFGS run (a check that never fires) give the result of one uninterrupted run."""
    target = _target(12, 12)
    init = np.random.default_rng(1).random((12, 12, 3)).astype(np.float32)
    a, ia = optimize_image(init, _l2_tv_builder(target), levels=1, iters=30)
    b, ib = optimize_image(init, _l2_tv_builder(target), levels=1, iters=30, converge=(7, -1.0))
    assert ib["levels"][0]["iterations"] == ia["levels"][0]["iterations"]
    np.testing.assert_allclose(a, b, atol=1e-6)



def test_deterministic_mode_is_on_while_optimising_and_restored_after():
    import torch.utils.deterministic as td

    seen = []

    def build(level, scale, shape):
        t = torch.full((1, 3) + tuple(shape), 0.25)

        def loss(x):
            seen.append((torch.are_deterministic_algorithms_enabled(), td.fill_uninitialized_memory))
            return {"l2": (x - t).square().sum()}
        return loss

    before = (torch.are_deterministic_algorithms_enabled(), td.fill_uninitialized_memory)
    optimize_image(np.full((8, 8, 3), 0.5, np.float32), build, levels=1, iters=3)
    assert seen and all(s == (True, False) for s in seen)
    assert (torch.are_deterministic_algorithms_enabled(), td.fill_uninitialized_memory) == before


@pytest.mark.parametrize("line_search", ["strong_wolfe", None])
def test_own_lbfgs_gives_torchs_iterates_bitwise(line_search):
    from facetex.transfer._lbfgs import LBFGS

    g = torch.Generator().manual_seed(0)
    a, target = torch.rand(40, 40, generator=g), torch.rand(40, generator=g)

    def run(cls):
        x = torch.zeros(40, requires_grad=True)
        opt = cls([x], lr=1.0, max_iter=7, max_eval=12, history_size=5, line_search_fn=line_search)

        def closure():
            opt.zero_grad(set_to_none=False)
            loss = (a @ x.tanh() - target).square().sum() + 0.1 * x.abs().pow(3).sum()  # not quadratic
            loss.backward()
            return loss

        trace = []
        for chunk in range(3):  # several step() calls keep the history, as optimize_image's chunks
            opt.param_groups[0].update(max_iter=5 + chunk, max_eval=9 + chunk)
            opt.step(closure)
            trace.append((x.detach().clone(), opt.state[x]["n_iter"], opt.state[x]["func_evals"]))
        return trace

    ours, torchs = run(LBFGS), run(torch.optim.LBFGS)
    assert ours[-1][1] > 10
    for (xa, na, ea), (xb, nb, eb) in zip(ours, torchs):
        assert torch.equal(xa, xb) and (na, ea) == (nb, eb)


def test_optimising_loads_no_compiler():
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        import sys, numpy as np, torch
        from facetex.transfer.optimize import optimize_image
        def build(level, scale, shape):
            t = torch.full((1, 3) + tuple(shape), 0.25)
            return lambda x: {"l2": (x - t).square().sum()}
        optimize_image(np.full((8, 8, 3), 0.5, np.float32), build, levels=2, iters=3, converge=(2, 0.01))
        print("torch._dynamo" in sys.modules, "torch._inductor" in sys.modules)
    """)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.split() == ["False", "False"]  # 1.1-1.5 CPU s per process when loaded
