"""FaceRecognitionNet against dlib itself (dlib is used only here, as the reference)."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
import torch

from facetex._resources import model_path, sample_path
from facetex.cli import main as cli_main
from facetex.errors import BadInputError, ModelNotFoundError
from facetex.io import read_image
from facetex.nets import _dlib_dat
from facetex.nets.dlib_resnet import (
    LAYER_NAMES,
    SAME_PERSON_THRESHOLD,
    FaceRecognitionNet,
    face_descriptor,
    identity_distance,
    pad_add,
)

dlib = pytest.importorskip("dlib")

FACES = ("frl_003_neutral", "frl_004_neutral", "frl_005_smiling", "frl_008_neutral")


@pytest.fixture(scope="module")
def net():
    return FaceRecognitionNet()


@pytest.fixture(scope="module")
def dlib_models():
    det = dlib.get_frontal_face_detector()
    sp = dlib.shape_predictor(str(model_path("shape_predictor_68_face_landmarks.dat")))
    rec = dlib.face_recognition_model_v1(str(model_path("dlib_face_recognition_resnet_model_v1.dat")))
    return det, sp, rec


@pytest.fixture(scope="module")
def chips(dlib_models):
    """dlib's own 150² chips of the bundled faces and dlib's descriptors of them."""
    det, sp, rec = dlib_models
    out = []
    for name in FACES:
        img = (read_image(sample_path(name + ".jpg")) * 255 + 0.5).astype(np.uint8)
        shape = sp(img, det(img, 0)[0])
        chip = dlib.get_face_chip(img, shape, size=150, padding=0.25)
        out.append((chip, np.array(rec.compute_face_descriptor(chip))))
    return out


def _batch(chips_u8):
    return torch.from_numpy(np.stack(chips_u8).astype(np.float32).transpose(0, 3, 1, 2) / 255.0)


def test_descriptor_matches_dlib(net, chips):
    x = _batch([c for c, _ in chips])
    with torch.no_grad():
        ours = net(x).double().numpy()
    ref = np.stack([d for _, d in chips])
    assert np.abs(ours - ref).max() <= 1e-4
    # dlib does not normalise its descriptors: neither do we
    assert not np.allclose(np.linalg.norm(ref, axis=1), 1.0, atol=0.05)


def test_architecture_and_parameter_count(net):
    convs = [m for m in net.modules() if isinstance(m, torch.nn.Conv2d)]
    assert len(convs) == 29
    assert sum(p.numel() for p in net.parameters()) == 5_614_592
    assert net.fc.weight.shape == (128, 256)
    assert torch.allclose(net.mean, torch.tensor([122.782, 117.001, 104.298]), atol=1e-3)
    assert not any(p.requires_grad for p in net.parameters())


def test_feature_shapes_and_early_stop(net, chips):
    x = _batch([chips[0][0]])
    with torch.no_grad():
        feats = net.features(x)
        only = net.features(x, ["conv1", "level2"])
    assert list(feats) == list(LAYER_NAMES)
    expect = {"conv1": (32, 72, 72), "pool1": (32, 35, 35), "level1": (32, 35, 35), "level2": (64, 17, 17),
              "level3": (128, 8, 8), "level4": (256, 4, 4), "level5": (256, 2, 2), "pool": (256,),
              "descriptor": (128,)}
    for name, shape in expect.items():
        assert tuple(feats[name].shape[1:]) == shape, name
    assert set(only) == {"conv1", "level2"}
    assert torch.equal(only["level2"], feats["level2"])
    with torch.no_grad():
        assert torch.equal(net(x), feats["descriptor"])
    with pytest.raises(BadInputError):
        net.features(x, ["nope"])


def test_larger_input_feature_maps(net):
    x = torch.rand(1, 3, 176, 160)
    with torch.no_grad():
        f = net.features(x, ["level3", "descriptor"])
    assert f["level3"].shape[:2] == (1, 128) and f["level3"].shape[2] > 8
    assert torch.isfinite(f["descriptor"]).all()
    with torch.no_grad():
        assert net(torch.rand(1, 3, 103, 103)).shape == (1, 128)
        with pytest.raises(BadInputError):
            net(torch.rand(1, 3, 102, 102))


def test_input_gradient_is_finite_and_nonzero(net, chips):
    x = _batch([chips[1][0]]).requires_grad_(True)
    f = net.features(x, ["level3", "descriptor"])
    (f["level3"].square().mean() + f["descriptor"].square().sum()).backward()
    g = x.grad
    assert torch.isfinite(g).all() and g.abs().sum() > 0


def test_pad_add_zero_pads_top_left():
    a = torch.ones(1, 1, 2, 2)
    b = torch.full((1, 2, 1, 3), 2.0)
    out = pad_add(a, b)
    expect = torch.tensor([[[[3.0, 3.0, 2.0], [1.0, 1.0, 0.0]], [[2.0, 2.0, 2.0], [0.0, 0.0, 0.0]]]])
    assert torch.equal(out, expect)


def test_dlib_number_encoding():
    r = _dlib_dat._Reader(b"\x81\x05" + b"\x02\x00\x01" + b"\x01\x03\x81\x02" + b"\x01\x05con_4", "x")
    assert r.int() == -5
    assert r.int() == 256
    assert r.float() == 0.75  # 3 * 2**-2
    assert r.str() == "con_4"


def test_truncated_model_file_raises(tmp_path):
    src = model_path("dlib_face_recognition_resnet_model_v1.dat").read_bytes()
    bad = tmp_path / "cut.dat"
    bad.write_bytes(src[: len(src) // 2])
    with pytest.raises(ModelNotFoundError):
        FaceRecognitionNet(bad)


def test_parsing_is_fast():
    t = time.perf_counter()
    from facetex.nets.dlib_resnet import _parsed

    _parsed.__wrapped__(str(model_path("dlib_face_recognition_resnet_model_v1.dat")))
    assert time.perf_counter() - t < 2.0


def test_same_and_different_people(dlib_models):
    det, sp, _ = dlib_models
    img, pts = {}, {}
    for n in ("004_neutral", "004_smiling", "005_neutral"):
        img[n] = read_image(sample_path(f"frl_{n}.jpg"))
        img8 = (img[n] * 255 + 0.5).astype(np.uint8)
        pts[n] = np.array([(p.x, p.y) for p in sp(img8, det(img8, 0)[0]).parts()], dtype=np.float64)
    desc = {n: face_descriptor(img[n], pts[n]) for n in img}
    same = np.linalg.norm(desc["004_neutral"] - desc["004_smiling"])
    diff = np.linalg.norm(desc["004_neutral"] - desc["005_neutral"])
    assert same < SAME_PERSON_THRESHOLD < diff
    assert desc["004_neutral"].shape == (128,) and desc["004_neutral"].dtype == np.float64
    d = identity_distance(img["004_neutral"], img["004_smiling"], points_a=pts["004_neutral"],
                          points_b=pts["004_smiling"])
    assert d == pytest.approx(same, abs=1e-9)


def test_face_descriptor_close_to_dlib_full_pipeline(dlib_models):
    det, sp, rec = dlib_models
    img = read_image(sample_path("frl_008_neutral.jpg"))
    img8 = (img * 255 + 0.5).astype(np.uint8)
    shape = sp(img8, det(img8, 0)[0])
    pts = np.array([(p.x, p.y) for p in shape.parts()], dtype=np.float64)
    ref = np.array(rec.compute_face_descriptor(img8, shape))
    assert np.linalg.norm(face_descriptor(img, pts) - ref) < 0.01
    assert np.linalg.norm(face_descriptor(img) - ref) < 0.05  # detects the face itself


def test_cli_identity_json(capsys):
    a, b = sample_path("frl_004_neutral.jpg"), sample_path("frl_005_neutral.jpg")
    assert cli_main(["identity", str(a), str(b), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"distance", "same_person"}
    assert isinstance(out["distance"], float) and out["same_person"] is False


def test_cli_identity_missing_file(capsys, tmp_path):
    code = cli_main(["identity", str(sample_path("frl_004_neutral.jpg")), str(tmp_path / "none.jpg")])
    assert code != 0
    err = capsys.readouterr().err
    assert "none.jpg" in err and len(err.strip().splitlines()) == 1


def test_folded_affines_compute_the_same_features(net):
    folded = FaceRecognitionNet().fold_affines()
    assert not any(type(m).__name__ == "Affine" for m in folded.modules())
    x = torch.rand(1, 3, 150, 150, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        a, b = net.features(x, ["level2", "level3", "descriptor"]), folded.features(x, ["level2", "level3", "descriptor"])
    for k in a:
        assert (a[k] - b[k]).abs().max() <= 1e-4 * a[k].abs().max(), k
