import numpy as np
import pytest
import skimage.data
import skimage.transform
import torch
import torch.nn.functional as F

from facetex._resources import model_path
from facetex.errors import BadInputError
from facetex.nets.effnet import EfficientNetLite0Features, _Conv2d


@pytest.fixture(scope="module")
def net():
    return EfficientNetLite0Features()


def _chelsea(size=224):
    img = skimage.data.chelsea().astype(np.float32) / 255.0
    img = skimage.transform.resize(img, (size, size), anti_aliasing=True).astype(np.float32)
    return torch.from_numpy(img).permute(2, 0, 1)[None]


@pytest.mark.parametrize("padding", ["same", "symmetric"])
def test_classifies_cat_photo_as_cat(padding):
    net = EfficientNetLite0Features(padding=padding)
    with torch.no_grad():
        logits = net.classify(_chelsea())
    assert logits.shape == (1, 1000)
    top5 = logits[0].topk(5).indices.tolist()
    assert top5[0] in range(281, 286)  # ImageNet tabby / tiger / Persian / Siamese / Egyptian cat
    assert sum(c in range(281, 286) for c in top5) >= 2


def test_strict_load_covers_every_stored_tensor(net):
    stored = torch.load(model_path("efficientnet-lite0-57934424.pth"), map_location="cpu", weights_only=True)
    assert set(net.state_dict()) == set(stored)
    assert torch.equal(net._blocks[7]._project_conv.weight, stored["_blocks.7._project_conv.weight"])
    assert not any(p.requires_grad for p in net.parameters())
    net.train()
    assert not net.training


def test_feature_shapes_and_strides_256(net):
    assert net.layer_names == ["stem"] + [f"block{i}" for i in range(16)] + ["head"]
    expected = {"stem": 2, "block0": 2, "block2": 4, "block4": 8, "block7": 16, "block10": 16,
                "block14": 32, "block15": 32, "head": 32}
    assert {k: net.strides[k] for k in expected} == expected
    with torch.no_grad():
        out = net.features(torch.rand(1, 3, 256, 256), net.layer_names)
    assert list(out) == net.layer_names
    for name, t in out.items():
        s = net.strides[name]
        assert t.shape == (1, net.channels[name], 256 // s, 256 // s), name
    assert out["block7"].shape[1] == 80 and out["head"].shape[1] == 1280


def test_features_returns_only_requested_and_stops_early(net):
    ran = []
    hooks = [b.register_forward_hook(lambda m, i, o, k=k: ran.append(k)) for k, b in enumerate(net._blocks)]
    try:
        with torch.no_grad():
            out = net.features(torch.rand(1, 3, 64, 64), ["block4", "block2"])
    finally:
        for h in hooks:
            h.remove()
    assert list(out) == ["block4", "block2"]
    assert ran == [0, 1, 2, 3, 4]
    with pytest.raises(BadInputError):
        net.features(torch.rand(1, 3, 64, 64), ["block99"])


def test_gradient_reaches_input(net):
    x = torch.rand(1, 3, 64, 64, requires_grad=True)
    net.features(x, ["block7"])["block7"].square().mean().backward()
    assert x.grad is not None and x.grad.abs().sum() > 0


@pytest.mark.parametrize("n, expected", [(5, (1, 1)), (6, (0, 1)), (7, (1, 1))])
def test_same_padding_matches_tensorflow(n, expected):
    # TF "SAME", k=3, s=2: out = ceil(n/2); total pad = (out-1)*2 + 3 - n, extra on the right.
    conv = _Conv2d(1, 1, 3, stride=2, same=True)
    torch.nn.init.normal_(conv.weight)
    x = torch.randn(1, 1, n, n)
    lo, hi = expected
    ref = F.conv2d(F.pad(x, (lo, hi, lo, hi)), conv.weight, stride=2)
    y = conv(x)
    assert y.shape[-1] == -(-n // 2)
    assert torch.allclose(y, ref, atol=1e-6)


def test_missing_weights_file(tmp_path):
    from facetex.errors import ModelNotFoundError

    with pytest.raises(ModelNotFoundError):
        EfficientNetLite0Features(weights=tmp_path / "none.pth")


def test_fused_batchnorm_computes_the_same_features():
    plain, fused = EfficientNetLite0Features(), EfficientNetLite0Features().fuse_batchnorm()
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in fused.modules())
    assert any(isinstance(m, torch.nn.BatchNorm2d) for m in plain.modules())
    x = torch.rand(1, 3, 67, 50, generator=torch.Generator().manual_seed(0))  # odd sizes: asymmetric "same" pads
    with torch.no_grad():
        a, b = plain.features(x, ["block2", "block4", "block7"]), fused.features(x, ["block2", "block4", "block7"])
    for k in a:
        assert (a[k] - b[k]).abs().max() <= 1e-4 * a[k].abs().max(), k
    assert not any(p.requires_grad for p in fused.parameters())


def test_same_padding_equals_tensorflow_padding_for_symmetric_and_asymmetric_cases():
    g = torch.Generator().manual_seed(1)
    for k, stride, n, pads in ((3, 1, 9, (1, 1)), (5, 1, 8, (2, 2)), (3, 2, 8, (0, 1)), (5, 2, 8, (1, 2))):
        conv = _Conv2d(4, 4, k, stride=stride, groups=4, same=True)
        x = torch.rand(1, 4, n, n, generator=g)
        ref = F.conv2d(F.pad(x, (pads[0], pads[1], pads[0], pads[1])), conv.weight, stride=stride, groups=4)
        assert conv(x).shape == ref.shape and torch.allclose(conv(x), ref, atol=1e-6), (k, stride)
