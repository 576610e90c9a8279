"""dlib's face-recognition ResNet (``dlib_face_recognition_resnet_model_v1.dat``) in torch.

The weights are read from dlib's own file by :mod:`._dlib_dat` (no dlib at run time);
the wiring, which the file does not store, is dlib's ``dnn_face_recognition_ex.cpp``:
a 7×7/2 convolution, 3×3/2 max-pool, then 14 residual blocks in five levels (32, 64,
128, 256, 256 channels), global average pool and a 256 → 128 linear map without bias.
Batch norms are folded into per-channel affines. Down-sampling blocks take a 3×3/2
convolution on the main path and a 2×2/2 average pool on the shortcut, both unpadded;
dlib adds tensors of different shapes by zero-padding them (top-left aligned), which
also makes the network run on inputs larger than 150².

Feature names (shapes for a 150² input; level numbers follow the data flow, i.e. dlib's
``alevel4`` is ``level1``)::

    conv1       (N, 32, 72, 72)   7×7/2 conv + affine + relu
    pool1       (N, 32, 35, 35)   3×3/2 max pool
    level1_1..3, level1  (N, 32, 35, 35)
    level2_1..4, level2  (N, 64, 17, 17)
    level3_1..3, level3  (N, 128, 8, 8)
    level4_1..3, level4  (N, 256, 4, 4)
    level5_1,    level5  (N, 256, 2, 2)
    pool        (N, 256)          global average
    descriptor  (N, 128)          the face descriptor (not normalised, as dlib)
"""

from __future__ import annotations

import functools
import threading
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from .._resources import model_path
from ..errors import BadInputError
from ._dlib_dat import DatFormatError, read_dnn

MODEL_FILE = "dlib_face_recognition_resnet_model_v1.dat"
SAME_PERSON_THRESHOLD = 0.6  # dlib's own decision threshold (loss_metric dist_thresh)
CHIP_SIZE = 150
CHIP_PADDING = 0.25
MIN_INPUT = 103  # smallest square input that reaches the descriptor

# (channels, blocks, first block down-samples)
_LEVELS = ((32, 3, False), (64, 4, True), (128, 3, True), (256, 3, True), (256, 1, True))


def _layer_names() -> tuple[str, ...]:
    names = ["conv1", "pool1"]
    for i, (_, blocks, _) in enumerate(_LEVELS, 1):
        names += [f"level{i}_{j}" for j in range(1, blocks + 1)] + [f"level{i}"]
    return tuple(names + ["pool", "descriptor"])


LAYER_NAMES = _layer_names()


def pad_add(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a + b for (N, C, H, W) tensors of different C/H/W: the smaller is zero-padded at the
    end of each axis, as dlib's ``add_prev``."""
    if a.shape == b.shape:
        return a + b
    c, h, w = (max(a.shape[i], b.shape[i]) for i in (1, 2, 3))

    def pad(t):
        return F.pad(t, (0, w - t.shape[3], 0, h - t.shape[2], 0, c - t.shape[1]))

    return pad(a) + pad(b)


class Affine(nn.Module):
    """Per-channel scale and shift (dlib's ``affine`` layer, a folded batch norm)."""

    def __init__(self, channels: int):
        super().__init__()
        self.weight = nn.Parameter(torch.ones(channels))
        self.bias = nn.Parameter(torch.zeros(channels))

    def forward(self, x):
        return x * self.weight[:, None, None] + self.bias[:, None, None]


class ResidualBlock(nn.Module):
    """relu(shortcut(x) + affine(conv(relu(affine(conv(x)))))), shortcut = 2×2/2 avg pool when
    down-sampling; shapes that differ are zero-padded before the addition."""

    def __init__(self, cin: int, cout: int, down: bool):
        super().__init__()
        self.down = down
        self.conv_a = nn.Conv2d(cin, cout, 3, stride=2 if down else 1, padding=0 if down else 1)
        self.affine_a = Affine(cout)
        self.conv_b = nn.Conv2d(cout, cout, 3, padding=1)
        self.affine_b = Affine(cout)

    def forward(self, x):
        y = self.affine_b(self.conv_b(F.relu(self.affine_a(self.conv_a(x)))))
        skip = F.avg_pool2d(x, 2, 2) if self.down else x
        return F.relu(pad_add(y, skip))


class FaceRecognitionNet(nn.Module):
    """dlib's 128-D face descriptor network. ``forward(x)``: x (N, 3, H, W) RGB in [0, 1]
    (a 150² dlib chip for descriptors; larger inputs work for feature maps) → (N, 128).

    Parameters are frozen (``requires_grad=False``); gradients flow to the input.
    """

    layer_names = LAYER_NAMES

    def __init__(self, path: str | Path | None = None):
        super().__init__()
        self.conv1 = nn.Conv2d(3, 32, 7, stride=2, padding=0)
        self.affine1 = Affine(32)
        levels, cin = [], 32
        for cout, blocks, down in _LEVELS:
            levels.append(nn.Sequential(*[ResidualBlock(cin if j == 0 else cout, cout, down and j == 0)
                                          for j in range(blocks)]))
            cin = cout
        self.levels = nn.ModuleList(levels)
        self.fc = nn.Linear(256, 128, bias=False)
        self.register_buffer("mean", torch.zeros(3))
        state = load_state_dict(path)
        self.load_state_dict(state)
        self.requires_grad_(False)
        self.eval()

    def fold_affines(self) -> "FaceRecognitionNet":
        """Fold every affine (folded batch norm) into the convolution before it, in place, and
        return the net: the same function (to float rounding) with one operation fewer per
        layer forward and backward (the transfer's structure loss; the state dict then no
        longer matches dlib's file)."""
        pairs = [(self, "conv1", "affine1")]
        for level in self.levels:
            for block in level:
                pairs += [(block, "conv_a", "affine_a"), (block, "conv_b", "affine_b")]
        with torch.no_grad():
            for owner, conv_name, affine_name in pairs:
                conv, affine = getattr(owner, conv_name), getattr(owner, affine_name)
                if isinstance(affine, Affine):
                    conv.weight.mul_(affine.weight[:, None, None, None])
                    conv.bias.mul_(affine.weight).add_(affine.bias)
                    setattr(owner, affine_name, nn.Identity())
        return self

    def _normalize(self, x: torch.Tensor) -> torch.Tensor:
        if x.ndim != 4 or x.shape[1] != 3:
            raise BadInputError(f"expected an (N, 3, H, W) RGB batch, got shape {tuple(x.shape)}")
        if min(x.shape[2:]) < 11:
            raise BadInputError(f"input of {x.shape[2]}x{x.shape[3]} px is too small: use at least "
                                f"{MIN_INPUT}x{MIN_INPUT} (11x11 for conv1/pool1 only)")
        return (x * 255.0 - self.mean[:, None, None]) / 256.0  # dlib input_rgb_image

    def features(self, x: torch.Tensor, layers=None) -> dict[str, torch.Tensor]:
        """Named intermediate outputs (see :data:`LAYER_NAMES`); stops after the deepest
        requested one. ``layers=None`` returns all."""
        wanted = list(LAYER_NAMES if layers is None else ([layers] if isinstance(layers, str) else layers))
        unknown = [n for n in wanted if n not in LAYER_NAMES]
        if unknown:
            raise BadInputError(f"unknown layer(s) {unknown}: choose from {', '.join(LAYER_NAMES)}")
        last = max(LAYER_NAMES.index(n) for n in wanted) if wanted else -1
        out: dict[str, torch.Tensor] = {}

        def keep(name, t):
            if name in wanted:
                out[name] = t
            return LAYER_NAMES.index(name) >= last

        x = F.relu(self.affine1(self.conv1(self._normalize(x))))
        if keep("conv1", x):
            return out
        x = F.max_pool2d(x, 3, 2)
        if keep("pool1", x):
            return out
        for i, level in enumerate(self.levels, 1):
            for j, block in enumerate(level, 1):
                if block.down and min(x.shape[2:]) < 3:
                    raise BadInputError(f"input too small to reach level{i}: use at least "
                                        f"{MIN_INPUT}x{MIN_INPUT} px")
                x = block(x)
                if keep(f"level{i}_{j}", x):
                    return out
            if keep(f"level{i}", x):
                return out
        x = x.mean(dim=(2, 3))
        if keep("pool", x):
            return out
        keep("descriptor", self.fc(x))  # dlib's fc: x @ W, W (256, 128)
        return out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.features(x, ["descriptor"])["descriptor"]


@functools.lru_cache(maxsize=4)
def _parsed(path: str) -> dict[str, torch.Tensor]:
    dnn = read_dnn(path)
    layers = list(dnn.layers)

    def take(kind):
        if not layers or layers[0].kind != kind:
            got = layers[0].kind if layers else "end of file"
            raise DatFormatError(f"expected a {kind} layer, found {got}: not dlib's face "
                                 "recognition ResNet v1", path=path)
        return layers.pop(0).params

    def affine(prefix, sd):
        p = take("affine") if layers and layers[0].kind == "affine" else None
        if p is None:  # a bn layer stored as in training: fold its running statistics
            b = take("bn")
            scale = b["gamma"] / np.sqrt(b["running_var"] + np.float32(b["eps"]))
            p = dict(gamma=scale, beta=b["beta"] - scale * b["running_mean"])
        sd[prefix + ".weight"] = torch.from_numpy(np.array(p["gamma"], dtype=np.float32))
        sd[prefix + ".bias"] = torch.from_numpy(np.array(p["beta"], dtype=np.float32))

    def conv(prefix, sd):
        p = take("con")
        sd[prefix + ".weight"] = torch.from_numpy(p["weight"].copy())
        bias = p["bias"] if p["bias"] is not None else np.zeros(p["weight"].shape[0], np.float32)
        sd[prefix + ".bias"] = torch.from_numpy(np.array(bias, dtype=np.float32))

    sd: dict[str, torch.Tensor] = {}
    inp = dnn.input
    sd["mean"] = torch.tensor([inp["avg_red"], inp["avg_green"], inp["avg_blue"]], dtype=torch.float32)
    conv("conv1", sd)
    affine("affine1", sd)
    take("relu")
    take("max_pool")
    for i, (_, blocks, down) in enumerate(_LEVELS):
        for j in range(blocks):
            pre = f"levels.{i}.{j}"
            conv(pre + ".conv_a", sd)
            affine(pre + ".affine_a", sd)
            take("relu")
            conv(pre + ".conv_b", sd)
            affine(pre + ".affine_b", sd)
            if down and j == 0:
                take("avg_pool")
            take("add_prev")
            take("relu")
    take("avg_pool")
    fc = take("fc")
    sd["fc.weight"] = torch.from_numpy(np.ascontiguousarray(fc["weight"].T))  # nn.Linear: (out, in)
    if layers:
        raise DatFormatError(f"{len(layers)} unexpected layer(s) at the end: not dlib's face "
                             "recognition ResNet v1", path=path)
    return sd


def load_state_dict(path: str | Path | None = None) -> dict[str, torch.Tensor]:
    """The network's state dict parsed from dlib's ``.dat`` (cached in memory per path)."""
    path = model_path(MODEL_FILE) if path is None else Path(path)
    return {k: v.clone() for k, v in _parsed(str(path)).items()}


# ---------------------------------------------------------------------------- descriptors

_net_lock = threading.Lock()
_net: FaceRecognitionNet | None = None


def default_net() -> FaceRecognitionNet:
    """A shared CPU instance of :class:`FaceRecognitionNet` (built on first use)."""
    global _net
    with _net_lock:
        if _net is None:
            _net = FaceRecognitionNet()
        return _net


def chip_descriptor(chip: np.ndarray) -> np.ndarray:
    """128-D descriptor (float64) of an aligned 150² RGB chip, float [0, 1] or uint8."""
    c = np.asarray(chip)
    if c.ndim != 3 or c.shape[2] != 3:
        raise BadInputError(f"expected an (H, W, 3) RGB chip, got shape {c.shape}")
    c = c.astype(np.float32) / 255.0 if c.dtype == np.uint8 else c.astype(np.float32, copy=False)
    x = torch.from_numpy(np.ascontiguousarray(c.transpose(2, 0, 1)))[None]
    with torch.no_grad():
        return default_net()(x)[0].double().numpy()


def face_descriptor(image: np.ndarray, points68=None, *, source=None) -> np.ndarray:
    """dlib's 128-D descriptor (float64) of the face in ``image`` (H, W, 3) float RGB in
    [0, 1] (or uint8); the largest face is detected when ``points68`` is not given
    (NoFaceError naming ``source`` when there is none)."""
    from .chip import face_chip

    img = np.asarray(image)
    if points68 is None:
        from ..landmarks import detect_face

        points68 = detect_face(img, source=source).points68
    if img.dtype == np.uint8:
        img = img.astype(np.float32) / 255.0
    return chip_descriptor(face_chip(img, points68, CHIP_SIZE, CHIP_PADDING))


def identity_distance(image_a: np.ndarray, image_b: np.ndarray, *, points_a=None, points_b=None,
                      source_a=None, source_b=None) -> float:
    """Euclidean distance between the descriptors of the (largest, or given) faces of two
    images; below :data:`SAME_PERSON_THRESHOLD` (0.6) dlib calls them the same person."""
    da = face_descriptor(image_a, points_a, source=source_a)
    db = face_descriptor(image_b, points_b, source=source_b)
    return float(np.linalg.norm(da - db))
