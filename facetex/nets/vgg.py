"""VGG-19 convolutional trunk as a frozen feature network with named layers.

Weights are never downloaded: they come from a local ``.pth`` in torchvision's
``vgg19-dcbb9e9d.pth`` layout (``features.0.weight`` …; classifier keys ignored), from the
torch hub cache, or are random (seeded Kaiming init). Architecture written out here because
torchvision cannot be imported with this CPU torch.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from ..errors import BadInputError, ModelNotFoundError
from .effnet import _run_until

VGG19_FILE = "vgg19-dcbb9e9d.pth"
_CFG = [[64, 64], [128, 128], [256, 256, 256, 256], [512, 512, 512, 512], [512, 512, 512, 512]]
_MEAN = (0.485, 0.456, 0.406)  # ImageNet RGB statistics, as torchvision's VGG expects
_STD = (0.229, 0.224, 0.225)


def hub_weights_path() -> Path:
    """Where torch hub keeps ``vgg19-dcbb9e9d.pth`` (``torch.hub.get_dir()/checkpoints``)."""
    return Path(torch.hub.get_dir()) / "checkpoints" / VGG19_FILE


def _layout() -> list[tuple[str, int, int, int]]:
    """(name, torchvision ``features`` index, c_in, c_out) for every layer; c = 0 for non-convs."""
    rows, idx, c_in = [], 0, 3
    for b, widths in enumerate(_CFG, start=1):
        for j, c_out in enumerate(widths, start=1):
            rows.append((f"conv{b}_{j}", idx, c_in, c_out))
            rows.append((f"relu{b}_{j}", idx + 1, 0, 0))
            idx, c_in = idx + 2, c_out
        rows.append((f"pool{b}", idx, 0, 0))
        idx += 1
    return rows


class VGG19Features(nn.Module):
    """Frozen VGG-19 trunk with named outputs ``conv1_1``, ``relu1_1``, …, ``pool1``, …, ``pool5``.

    ``weights``: a ``.pth`` path (torchvision layout), None (the torch hub cache file), or
    ``"random"`` (Kaiming-normal init from ``seed``, deterministic). Raises ModelNotFoundError
    when the file is missing. ``pool``: ``"max"`` (as trained) or ``"avg"`` (Gatys et al.).
    Input: (N, 3, H, W) float RGB in [0, 1]; ImageNet mean/std normalisation is applied inside.
    """

    def __init__(self, weights: str | os.PathLike | None = None, pool: str = "max", seed: int = 0):
        super().__init__()
        if pool not in ("max", "avg"):
            raise BadInputError(f"pool must be 'max' or 'avg', not {pool!r}")
        self.pool = pool
        rows = _layout()
        self.layer_names = [r[0] for r in rows]
        self.convs = nn.ModuleDict({n: nn.Conv2d(ci, co, 3, padding=1) for n, _, ci, co in rows if co})
        self._index = {n: i for n, i, _, co in rows if co}  # conv name -> torchvision features index
        self.strides, self.channels, s, c = {}, {}, 1, 3
        for name, _, _, co in rows:
            c = co or c
            if name.startswith("pool"):
                s *= 2
            self.strides[name], self.channels[name] = s, c
        self.register_buffer("mean", torch.tensor(_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(_STD).view(1, 3, 1, 1), persistent=False)

        if isinstance(weights, str) and weights == "random":
            self._init_random(seed)
            self.weights = "random"
        else:
            path = hub_weights_path() if weights is None else Path(weights)
            self.load_torchvision(path)
            self.weights = str(path)
        self.requires_grad_(False)
        self.eval()

    def _init_random(self, seed: int) -> None:
        # fan_in keeps the activation variance roughly constant through the 16 ReLU convs.
        g = torch.Generator().manual_seed(seed)
        for conv in self.convs.values():
            nn.init.kaiming_normal_(conv.weight, mode="fan_in", nonlinearity="relu", generator=g)
            nn.init.zeros_(conv.bias)

    def load_torchvision(self, path: str | os.PathLike) -> None:
        """Strictly load the ``features.*`` tensors of a torchvision VGG-19 state dict."""
        path = Path(path)
        if not path.is_file():
            hub = hub_weights_path()
            where = str(hub) if path == hub else f"{path} or {hub}"
            raise ModelNotFoundError(
                f"VGG-19 weights not found (facetex never downloads them): put torchvision's {VGG19_FILE} "
                f"at {where}, or point --vgg19-weights PATH to it", path=path)
        try:
            state = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as e:  # truncated download, not a torch file, ...
            raise ModelNotFoundError(f"cannot read VGG-19 weights ({type(e).__name__}): replace the file with "
                                     f"torchvision's {VGG19_FILE}", path=path) from e
        mine = {}
        for name, idx in self._index.items():
            for p in ("weight", "bias"):
                mine[f"{name}.{p}"] = state.get(f"features.{idx}.{p}")
        missing = [k for k, v in mine.items() if v is None]
        if missing:
            raise ModelNotFoundError(
                f"not a torchvision VGG-19 state dict (missing features.* keys for {missing[:3]}…): "
                f"use {VGG19_FILE}", path=path)
        self.convs.load_state_dict(mine, strict=True)

    def train(self, mode: bool = True) -> "VGG19Features":
        return super().train(False)  # frozen feature network

    def _stages(self):
        yield None, lambda x: (x - self.mean) / self.std
        for name in self.layer_names:
            if name.startswith("conv"):
                yield name, self.convs[name]
            elif name.startswith("relu"):
                yield name, F.relu  # not in place: the conv output may be returned too
            elif self.pool == "max":
                yield name, lambda x: F.max_pool2d(x, 2, 2)
            else:
                yield name, lambda x: F.avg_pool2d(x, 2, 2)

    def features(self, x: torch.Tensor, layers: list[str]) -> dict[str, torch.Tensor]:
        """The requested named outputs; the forward pass stops at the deepest one."""
        return _run_until(self._stages(), self.layer_names, x, layers)

    def forward(self, x: torch.Tensor, layers: list[str] | None = None) -> dict[str, torch.Tensor]:
        """``features(x, layers)``; all named outputs when ``layers`` is None."""
        return self.features(x, self.layer_names if layers is None else layers)

