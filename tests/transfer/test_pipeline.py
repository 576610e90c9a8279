"""End-to-end FaceTex transfer on small real faces (bundled samples), kept fast by size/iters."""

import json

import numpy as np
import pytest

import facetex
from facetex._resources import sample_path
from facetex.errors import BadInputError, MemoryBudgetError, NoFaceError
from facetex.io import read_image
from facetex.landmarks import detect_face
from facetex.transfer import estimate_transfer_memory, face_crop_box, preset, transfer_with_info

FAST = dict(size=96, iters=(4, 4, 4))


@pytest.fixture(scope="module")
def faces():
    c = read_image(sample_path("frl_004_neutral.jpg"))
    s = read_image(sample_path("frl_005_neutral.jpg"))
    return c, s, detect_face(c).points68, detect_face(s).points68


@pytest.mark.parametrize("method", ["facetex", "mrf", "gatys"])
def test_methods_run_and_keep_background(faces, method):
    c, s, pc, ps = faces
    out, info = transfer_with_info(c, s, method=method, content_points=pc, style_points=ps, **FAST)
    assert out.shape == c.shape and out.dtype == np.float32
    assert 0.0 <= out.min() and out.max() <= 1.0
    x0, y0, x1, y1 = info["region_box"]
    outside = np.ones(c.shape[:2], bool)
    outside[y0:y1, x0:x1] = False
    assert np.array_equal(out[outside], c[outside])  # only the face crop is touched
    changed = np.abs(out - c)[y0:y1, x0:x1].mean()
    assert changed > 1e-3  # the optimisation did something
    assert [lvl["shape"] for lvl in info["levels"]][-1] == tuple(info["working_shape"])
    assert info["method"] == method and info["timings"]["total_s"] > 0


def test_facetex_prior_freezes_background_of_crop(faces):
    c, s, pc, ps = faces
    out, info = transfer_with_info(c, s, method="facetex", content_points=pc, style_points=ps, **FAST)
    face = info["images"]["face"]
    w = info["images"]["output_w"] - info["images"]["content_w"]
    # the prior × face mask blocks the network gradients off the face; only TV can act there
    assert np.abs(w[face < 0.01]).mean() < 0.25 * np.abs(w[face > 0.99]).mean()


def test_deterministic_with_seed(faces):
    c, s, pc, ps = faces
    a = transfer_with_info(c, s, content_points=pc, style_points=ps, seed=3, **FAST)[0]
    b = transfer_with_info(c, s, content_points=pc, style_points=ps, seed=3, **FAST)[0]
    assert np.array_equal(a, b)


def test_callable_module_and_uint8_input(faces):
    c, s, pc, ps = faces
    out = facetex.transfer((c * 255).astype(np.uint8), s, content_points=pc, style_points=ps, size=64, iters=(2,))
    assert out.shape == c.shape


def test_memory_budget_refuses(faces):
    c, s, pc, ps = faces
    with pytest.raises(MemoryBudgetError, match="--size"):
        transfer_with_info(c, s, content_points=pc, style_points=ps, max_memory=2**20, **FAST)


def test_memory_estimate_grows_with_size():
    p = preset("facetex", "paper")
    small, large = estimate_transfer_memory(p, (250, 250)), estimate_transfer_memory(p, (1000, 1000))
    assert large > 4 * small * 0.8 - 4 * 550 * 2**20  # ~quadratic in the side, above the fixed part
    assert large < 8 * 2**30  # the paper preset at 1000 px fits the 8 GB target


def test_no_face_names_source(faces):
    c, s, pc, ps = faces
    blank = np.full((200, 200, 3), 0.5, np.float32)
    with pytest.raises(NoFaceError, match="blank.png"):
        transfer_with_info(blank, s, style_points=ps, content_source="blank.png", **FAST)


def test_bad_options(faces):
    c, s, pc, ps = faces
    with pytest.raises(BadInputError, match="unknown transfer option"):
        transfer_with_info(c, s, content_points=pc, style_points=ps, colour="red")
    with pytest.raises(BadInputError, match="unknown method"):
        transfer_with_info(c, s, method="cyclegan", content_points=pc, style_points=ps)


def test_upscaling_warns(faces):
    c, s, pc, ps = faces
    with pytest.warns(UserWarning, match="upscaled"):
        transfer_with_info(c, s, content_points=pc, style_points=ps, size=300, iters=(0,))


def test_face_crop_box_contains_landmarks(faces):
    c, _, pc, _ = faces
    x0, y0, x1, y1 = face_crop_box(pc, c.shape)
    assert x0 < pc[:, 0].min() and pc[:, 0].max() < x1
    assert y0 < pc[:, 1].min() and pc[:, 1].max() < y1
    assert 0 <= x0 and x1 <= c.shape[1] and 0 <= y0 and y1 <= c.shape[0]


def test_cli_transfer_writes_output_and_sidecar(tmp_path, capsys):
    from facetex.cli import main

    out = tmp_path / "out.png"
    args = ["transfer", str(sample_path("frl_004_neutral.jpg")), str(sample_path("frl_005_neutral.jpg")),
            "-o", str(out), "--size", "64", "--iters", "2,2", "--seed", "1"]
    assert main(args) == 0
    info = json.loads((tmp_path / "out.png.json").read_text())
    assert info["seed"] == 1 and info["params"]["iters"] == [2, 2] and "images" not in info
    assert read_image(out).shape == (400, 400, 3)
    # an existing output is not overwritten without --overwrite
    before = out.read_bytes()
    assert main(args) != 0
    assert "--overwrite" in capsys.readouterr().err
    assert out.read_bytes() == before
