import pytest
import torch
import torch.nn.functional as F

from facetex.errors import ModelNotFoundError
from facetex.nets.vgg import VGG19Features

# torchvision vgg19().features: conv indices and shapes, max-pools at 4, 9, 18, 27, 36.
_CONVS = {0: (64, 3), 2: (64, 64), 5: (128, 64), 7: (128, 128), 10: (256, 128), 12: (256, 256),
          14: (256, 256), 16: (256, 256), 19: (512, 256), 21: (512, 512), 23: (512, 512), 25: (512, 512),
          28: (512, 512), 30: (512, 512), 32: (512, 512), 34: (512, 512)}
_POOLS = {4, 9, 18, 27, 36}


@pytest.fixture(scope="module")
def fake_weights(tmp_path_factory):
    g = torch.Generator().manual_seed(1)
    sd = {}
    for i, (co, ci) in _CONVS.items():
        sd[f"features.{i}.weight"] = torch.randn(co, ci, 3, 3, generator=g) * (2.0 / (9 * ci)) ** 0.5
        sd[f"features.{i}.bias"] = torch.randn(co, generator=g) * 0.1
    sd["classifier.6.weight"] = torch.randn(1000, 4096, generator=g)  # ignored
    sd["classifier.6.bias"] = torch.randn(1000, generator=g)
    path = tmp_path_factory.mktemp("vgg") / "vgg19-dcbb9e9d.pth"
    torch.save(sd, path)
    return path, sd


def _reference(sd, x, upto):
    """torchvision's Sequential semantics, run by hand up to features index ``upto``."""
    x = (x - torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)) / torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
    for i in range(upto + 1):
        if i in _CONVS:
            x = F.conv2d(x, sd[f"features.{i}.weight"], sd[f"features.{i}.bias"], padding=1)
        elif i in _POOLS:
            x = F.max_pool2d(x, 2)
        else:
            x = F.relu(x)
    return x


def test_loads_torchvision_layout_and_follows_weights(fake_weights):
    path, sd = fake_weights
    net = VGG19Features(path)
    x = torch.rand(1, 3, 48, 48)
    with torch.no_grad():
        out = net.features(x, ["conv1_1", "pool2", "relu3_1", "relu4_2"])
    assert torch.allclose(out["conv1_1"], _reference(sd, x, 0), atol=1e-5)
    assert torch.allclose(out["pool2"], _reference(sd, x, 9), atol=1e-5)
    assert torch.allclose(out["relu3_1"], _reference(sd, x, 11), atol=1e-4)
    assert torch.allclose(out["relu4_2"], _reference(sd, x, 22), atol=1e-4, rtol=1e-4)
    assert not any(p.requires_grad for p in net.parameters()) and not net.training


def test_hub_cache_location_is_used(fake_weights, tmp_path, monkeypatch):
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path))
    with pytest.raises(ModelNotFoundError) as e:
        VGG19Features()
    assert str(tmp_path / "checkpoints" / "vgg19-dcbb9e9d.pth") in str(e.value)
    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "checkpoints" / "vgg19-dcbb9e9d.pth").symlink_to(fake_weights[0])
    net = VGG19Features()
    assert torch.equal(net.convs["conv5_4"].weight, fake_weights[1]["features.34.weight"])


def test_missing_file_names_both_locations(tmp_path):
    missing = tmp_path / "nope" / "vgg19.pth"
    with pytest.raises(ModelNotFoundError) as e:
        VGG19Features(missing)
    msg = str(e.value)
    assert e.value.path == str(missing)
    assert str(missing) in msg and "checkpoints" in msg and "--vgg19-weights PATH" in msg
    assert "\n" not in msg


def test_random_weights_deterministic_per_seed():
    x = torch.rand(1, 3, 32, 32)
    a, b, c = (VGG19Features("random", seed=s) for s in (3, 3, 4))
    with torch.no_grad():
        fa, fb, fc = (n.features(x, ["relu2_1"])["relu2_1"] for n in (a, b, c))
    assert torch.equal(fa, fb)
    assert not torch.allclose(fa, fc)
    w = a.convs["conv3_1"].weight
    assert abs(w.std().item() - (2.0 / (128 * 9)) ** 0.5) < 0.1 * (2.0 / (128 * 9)) ** 0.5  # Kaiming fan_in


def test_names_shapes_strides_and_early_stop():
    net = VGG19Features("random", pool="avg")
    assert net.layer_names[:5] == ["conv1_1", "relu1_1", "conv1_2", "relu1_2", "pool1"]
    assert "relu4_2" in net.layer_names and net.layer_names[-1] == "pool5" and len(net.layer_names) == 37
    assert [net.strides[n] for n in ("relu1_1", "pool1", "relu3_1", "relu4_1", "relu5_1", "pool5")] == [1, 2, 4, 8, 16, 32]
    ran = []
    hooks = [c.register_forward_hook(lambda m, i, o, k=k: ran.append(k)) for k, c in net.convs.items()]
    with torch.no_grad():
        out = net.features(torch.rand(1, 3, 64, 64), ["relu3_1", "relu1_2", "pool1"])
    for h in hooks:
        h.remove()
    assert ran == ["conv1_1", "conv1_2", "conv2_1", "conv2_2", "conv3_1"]
    assert list(out) == ["relu3_1", "relu1_2", "pool1"]
    assert out["relu3_1"].shape == (1, 256, 16, 16)
    assert torch.allclose(out["pool1"], F.avg_pool2d(out["relu1_2"], 2))


def test_gradient_reaches_input():
    net = VGG19Features("random")
    x = torch.rand(1, 3, 32, 32, requires_grad=True)
    net.features(x, ["relu2_1"])["relu2_1"].sum().backward()
    assert x.grad.abs().sum() > 0


def test_corrupt_file_is_model_not_found(tmp_path):
    bad = tmp_path / "vgg19-dcbb9e9d.pth"
    bad.write_bytes(b"<html>not a checkpoint</html>")
    with pytest.raises(ModelNotFoundError, match="cannot read"):
        VGG19Features(bad)
