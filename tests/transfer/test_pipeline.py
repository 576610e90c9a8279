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


def test_paper_prior_freezes_background_of_crop(faces):
    c, s, pc, ps = faces
    out, info = transfer_with_info(c, s, method="facetex", content_points=pc, style_points=ps, prior=True,
                                   constraint=None, detail=False, **FAST)
    face = info["images"]["face"]
    w = info["images"]["output_w"] - info["images"]["content_w"]
    # the prior × face mask blocks the network gradients off the face; only TV can act there
    assert np.abs(w[face < 0.01]).mean() < 0.25 * np.abs(w[face > 0.99]).mean()


def test_default_facetex_changes_only_the_skin(faces):
    """The hard constraint: eyes, brows, lips, nostrils, hair and background stay exactly as they were."""
    from facetex.geometry.skin import protected_mask

    c, s, pc, ps = faces
    out, info = transfer_with_info(c, s, method="facetex", content_points=pc, style_points=ps, **FAST)
    x0, y0, x1, y1 = info["region_box"]
    skin = np.zeros(c.shape[:2], np.float32)
    skin[y0:y1, x0:x1] = info["images"]["skin_content"]
    assert np.array_equal(out[skin == 0], c[skin == 0])
    assert np.abs(out - c)[skin > 0.9].mean() > 2e-3  # and the skin did change
    assert skin[protected_mask(pc, c.shape)].max() == 0.0
    assert info["prewarp_folds"] == 0


def test_prewarp_of_the_crop_equals_the_full_image_prewarp(faces):
    """The style the optimiser sees is the same morph the full images would give (no squeezing)."""
    from facetex.geometry.style_align import align_style_to_content

    c, s, pc, ps = faces
    _, info = transfer_with_info(c, s, content_points=pc, style_points=ps, **FAST)
    x0, y0, x1, y1 = info["region_box"]
    full = align_style_to_content(s, c, style_points=ps, content_points=pc, refine="optical-flow",
                                  interpolation="lanczos").image[y0:y1, x0:x1]
    crop = info["images"]["style_native"]
    inner = (slice(20, -20), slice(20, -20))
    assert np.abs(crop[inner] - full[inner]).mean() < 0.02


def test_detail_stage_brings_the_style_detail(faces):
    """An airbrushed content (blurred, no beard) gets the style's fine detail back."""
    import cv2

    from facetex.geometry.style_align import align_style_to_content
    from facetex.metrics import skin_detail

    _, s, _, ps = faces
    c = cv2.GaussianBlur(read_image(sample_path("frl_003_neutral.jpg")), (0, 0), 1.2)
    pc = detect_face(c).points68
    aligned = align_style_to_content(s, c, style_points=ps, content_points=pc, refine=None,
                                     interpolation="lanczos").image

    def cheeks(img):  # both faces' foreheads are under a fringe here: not skin
        # the metric's σ = 2 px is meant for ~330 px wide faces: these are 130 px wide
        per = skin_detail(img, pc, sigma=0.8, per_patch=True)[1]
        return (per["left_cheek"] + per["right_cheek"]) / 2

    target = cheeks(aligned)
    assert cheeks(c) < 0.8 * target
    with_d, info = transfer_with_info(c, s, content_points=pc, style_points=ps, **FAST)
    without, _ = transfer_with_info(c, s, content_points=pc, style_points=ps, detail=False, **FAST)
    d_with, d_without = cheeks(with_d), cheeks(without)
    assert d_with > d_without + 0.3 * (target - d_without)
    assert info["detail"]["gain_style"] and info["images"]["optimised_region"] is not None


def test_callback_gets_the_full_size_step(faces):
    c, s, pc, ps = faces
    got = []
    transfer_with_info(c, s, content_points=pc, style_points=ps, size=64, iters=(2, 2), save_every=2,
                       callback=lambda **kw: got.append(kw))
    assert got and all(k["full_image"].shape == c.shape for k in got)
    assert all(len(k["box"]) == 4 for k in got)


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


def test_no_style_hair_reaches_the_output():
    """A style with a skin-coloured (blond) fringe, which a colour test takes for skin: the
    content's forehead gets skin detail, not the strands."""
    import cv2

    from facetex.geometry.masks import face_width

    c = read_image(sample_path("frl_005_neutral.jpg"))
    s = read_image(sample_path("frl_004_neutral.jpg"))
    pc, ps = detect_face(c).points68, detect_face(s).points68
    fw = face_width(ps)
    top = int(ps[17:27, 1].min())
    ys, xs = slice(top - int(0.45 * fw), top - int(0.04 * fw)), slice(int(ps[17, 0]), int(ps[26, 0]))
    x = np.arange(xs.stop - xs.start)[None, :, None]
    s = s.copy()
    s[ys, xs] = np.clip(s[ys, xs] * (1.0 + 0.35 * np.sin(2 * np.pi * x / 5.0)), 0, 1)  # strands 2-3 px
    out, info = transfer_with_info(c, s, content_points=pc, style_points=ps, **FAST)
    im = info["images"]
    x0, y0 = info["region_box"][:2]
    ctop = int(pc[17:27, 1].min()) - y0
    fore = np.zeros(im["skin_content"].shape, bool)
    fore[max(0, ctop - 25):ctop - 5, int(pc[19, 0]) - x0:int(pc[24, 0]) - x0] = True
    fore &= im["skin_content"] > 0.9
    assert fore.sum() > 100
    luma = lambda x: x @ np.array([0.299, 0.587, 0.114], np.float32)  # noqa: E731
    hp = lambda x: x - cv2.GaussianBlur(x, (0, 0), 2.0)  # noqa: E731
    strands = hp(luma(im["style_native"]))[fore]
    assert strands.std() > 0.02  # the aligned style has its strands there
    change = hp(luma(im["output_region"] - im["region"]))[fore]
    assert change.std() > 1e-3  # the forehead did change
    assert abs(np.corrcoef(change, strands)[0, 1]) < 0.15


def test_style_patches_are_the_skin_ones_and_at_least_the_most_skin_like_few():
    """Patches whose centre is skin; with fewer than MIN_STYLE_PATCHES skin centres (a coarse
    level), the most skin-like ones, never the whole image (hair and background); a level with
    no skin at all keeps every patch."""
    import torch

    from facetex.transfer._levels import MIN_STYLE_PATCHES, _masked_style_patches
    from facetex.transfer.methods import preset

    p = preset("facetex", "default")
    feat = torch.rand(1, 4, 20, 20, generator=torch.Generator().manual_seed(0))
    all_n = len(_masked_style_patches(feat, torch.ones(1, 1, 20, 20), p))
    mask = torch.zeros(1, 1, 20, 20)
    mask[..., :10, :] = 1.0  # the top half is skin
    half = len(_masked_style_patches(feat, mask, p))
    assert MIN_STYLE_PATCHES <= half < all_n
    few = torch.zeros(1, 1, 20, 20)
    few[..., 9:12, 9:12] = 1.0  # a few skin centres, a soft rim around them
    few[..., 7:14, 7:14] = torch.maximum(few[..., 7:14, 7:14], torch.tensor(0.3))
    assert len(_masked_style_patches(feat, few, p)) == MIN_STYLE_PATCHES
    assert len(_masked_style_patches(feat, torch.zeros(1, 1, 20, 20), p)) == all_n


def test_missing_face_mesh_model_falls_back_with_a_warning(monkeypatch):
    """A wheel built offline has no face-mesh model: the skin mask falls back to the landmark
    outline, and the user is told (results differ); no face for the mesh falls back quietly."""
    import warnings

    import facetex.landmarks as lm
    from facetex.errors import ModelNotFoundError
    from facetex.transfer._pipeline import _face_mesh

    img, pts = np.zeros((8, 8, 3), np.float32), np.zeros((68, 2))

    def missing(*a, **k):
        raise ModelNotFoundError("model file face_landmark.tflite not found")

    monkeypatch.setattr(lm, "face_mesh468", missing)
    with pytest.warns(RuntimeWarning, match="face-mesh model unavailable"):
        assert _face_mesh(img, pts) is None

    def no_face(*a, **k):
        raise NoFaceError("no face")

    monkeypatch.setattr(lm, "face_mesh468", no_face)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _face_mesh(img, pts) is None
