"""``--size`` too small for the MRF patches at the coarsest level (issue 23): refused before any
work with the smallest size that works, not after the set-up ("feature map side 2 is smaller
than the patch size 3")."""

from __future__ import annotations

import re

import pytest

import facetex.io as fio
import facetex.transfer._pipeline as pipeline
from _robust import FACE, OTHER, assert_one_error, run_cli, snapshot


@pytest.fixture
def no_optimise(monkeypatch):
    def trap(*a, **k):
        raise AssertionError("the optimisation started before the size was checked")

    monkeypatch.setattr(pipeline, "optimize_image", trap)


def test_size_64_refused_before_reading(capsys, outdir, monkeypatch, no_optimise):
    for mod in (fio, fio._read):  # facetex.io's callers and as_image, beside read_image
        monkeypatch.setattr(mod, "read_image", lambda *a, **k: pytest.fail("an image was read before the check"))
    run = run_cli(capsys, "transfer", FACE, OTHER, "-o", outdir / "t.png", "--size", "64")
    line = assert_one_error(run, cause=r"size 64 px is too small .* use --size 65 or more")
    assert "--size" in line and snapshot(outdir) == {}


def test_size_of_a_narrow_face_region(capsys, outdir, no_optimise):
    """Square regions need 65 px, this face crop (taller than wide) more: named with the file."""
    run = run_cli(capsys, "transfer", FACE, OTHER, "-o", outdir / "t.png", "--size", "70")
    line = assert_one_error(run, names=[FACE], cause=r"face region .* too narrow .* use --size \d+ or more")
    need = int(re.search(r"--size (\d+) or more", line).group(1))
    assert 70 < need < 128 and snapshot(outdir) == {}


def test_suggested_size_works(capsys, outdir):
    run = run_cli(capsys, "transfer", FACE, OTHER, "-o", outdir / "t.png", "--size", "70")
    need = re.search(r"--size (\d+) or more", run.err).group(1)
    ok = run_cli(capsys, "transfer", FACE, OTHER, "-o", outdir / "t.png", "--size", need, "--iters", "1,1,1")
    assert ok.code == 0, ok.err
    below = run_cli(capsys, "transfer", FACE, OTHER, "-o", outdir / "u.png", "--size", int(need) - 1)
    assert_one_error(below, names=[FACE], cause=f"use --size {need} or more")


@pytest.mark.parametrize("levels, ok", [((2,), True), ((2, 2), True), ((2, 2, 2), False)])
def test_fewer_levels_allow_small_sizes(levels, ok):
    """The limit is of the coarsest level: 64 px works with one or two levels."""
    from facetex.errors import BadInputError
    from facetex.transfer.methods import preset

    if ok:
        preset().with_options(size=64, iters=levels)
    else:
        with pytest.raises(BadInputError, match=r"use --size 65"):
            preset().with_options(size=64, iters=levels)


def test_api_size_64(no_optimise):
    import facetex
    from facetex.errors import BadInputError

    with pytest.raises(BadInputError, match=r"size 64 px is too small.*65") as e:
        facetex.transfer(FACE, OTHER, size=64)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("net, method", [("vgg19-random", "mrf"), ("face-resnet", "facetex"),
                                         ("effnet-lite0", "facetex")])
def test_min_size_holds_a_patch(net, method):
    """At min_size the deepest MRF layer really holds a patch at the coarsest level, below it not."""
    import math

    import torch

    from facetex.transfer._levels import _texture_net
    from facetex.transfer.methods import NET_LAYERS, preset, working_shape

    p = preset(method, "default", net.replace("-random", ""))  # vgg19's shapes, without its weights file
    layer = NET_LAYERS[net.replace("-random", "")]["mrf"][-1]
    model = _texture_net(net, "cpu", None)
    def feature_side(region, size):
        side = math.ceil(min(working_shape(*region, size)) / 4)
        with torch.no_grad():
            return min(model.features(torch.zeros(1, 3, side, side), [layer])[layer].shape[-2:])

    for region in ((1, 1), (209, 162)):
        size = p.min_size(region)
        assert feature_side(region, size) >= p.patch_size, (net, region, size)
        if net != "face-resnet":  # exact for these (a lower bound for dlib's network)
            assert feature_side(region, size - 1) < p.patch_size, (net, region, size)
