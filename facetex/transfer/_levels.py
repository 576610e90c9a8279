"""What each resolution level of the transfer evaluates: the feature networks, the style's skin
patches, the weighted loss terms (FaceTex Eqs. 2, 3, 4, 6), and the memory they take."""

from __future__ import annotations

import functools

import numpy as np
import torch

from .._memory import available_memory
from .losses import (
    StylePatches,
    _grid,
    channel_softmax,
    gram_loss,
    gram_matrix,
    mrf_loss,
    mrf_memory_estimate,
    style_patches,
    tv_loss,
)
from .methods import TransferParams
from .optimize import _resize as _resize_level
from .optimize import to_tensor
from .prior import apply_facial_prior


# ---------------------------------------------------------------- networks
@functools.lru_cache(maxsize=4)
def _texture_net(name: str, device: str, vgg19_weights: str | None):
    if name == "effnet-lite0":
        from ..nets.effnet import EfficientNetLite0Features

        net = EfficientNetLite0Features().fuse_batchnorm()  # frozen: batch norms folded into the convolutions
    elif name == "vgg19":
        from ..nets.vgg import VGG19Features

        net = VGG19Features(weights=vgg19_weights) if vgg19_weights else VGG19Features()
    elif name == "vgg19-random":
        from ..nets.vgg import VGG19Features

        net = VGG19Features(weights="random")
    else:
        from ..nets.dlib_resnet import FaceRecognitionNet

        net = FaceRecognitionNet().fold_affines()
    return net.to(device).to(memory_format=torch.channels_last)  # see _features


@functools.lru_cache(maxsize=2)
def _structure_net(device: str):
    from ..nets.dlib_resnet import FaceRecognitionNet

    # affines folded into the convolutions, channels-last weights (speed, see _features)
    return FaceRecognitionNet().fold_affines().to(device).to(memory_format=torch.channels_last)


def _features(net, x: torch.Tensor, layers) -> dict[str, torch.Tensor]:
    """``net.features(x, layers)`` run channels-last (its depthwise and 1×1 convolutions take
    30 % less time forward + backward on CPU: EfficientNet-Lite0 at 384 × 296 px 63 → 44 ms),
    the maps returned in the usual contiguous layout."""
    out = net.features(x.contiguous(memory_format=torch.channels_last), list(layers))
    return {k: v.contiguous() for k, v in out.items()}


# ---------------------------------------------------------------- memory
_BYTES_PER_PIXEL = {  # measured peak bytes per working-region pixel of one forward+backward
    "effnet-lite0": 1800, "vgg19": 9000, "vgg19-random": 9000, "face-resnet": 2400,
}


def default_max_memory() -> int:
    """75 % of the available RAM."""
    return int(0.75 * available_memory())


def estimate_transfer_memory(params: TransferParams, shape: tuple[int, int]) -> int:
    """Estimated peak bytes of a transfer whose finest level is ``shape`` (h, w)."""
    h, w = shape
    px = h * w
    net = params.texture_net
    total = 550 * 2**20  # interpreter, torch, dlib models, the networks' weights (measured, benchmarks/memory.py)
    total += _BYTES_PER_PIXEL.get(net, 9000) * px  # activations for forward + backward
    if params.structure_weight:
        total += 60 * 2**20  # face chip through FaceRecognitionNet
    stride = {"effnet-lite0": (4, 8), "vgg19": (4, 8), "face-resnet": (4, 8)}.get(net, (4, 8))
    chans = {"effnet-lite0": (24, 40), "vgg19": (256, 512), "face-resnet": (32, 64)}.get(net, (256, 512))
    for s, c in zip(stride, chans):
        if params.mrf_weight:
            hw = (max(3, h // s), max(3, w // s))
            total += mrf_memory_estimate(c, hw, hw, patch_size=params.patch_size, style_stride=params.style_stride)
    total += 2 * params.lbfgs_history * 3 * px * 4  # L-BFGS curvature pairs
    total += 40 * px * 4  # images, masks, pyramids
    return int(total)


# ---------------------------------------------------------------- losses per level
#: a level's MRF loss matches against at least this many style patches (the most skin-like ones)
MIN_STYLE_PATCHES = 16


def _masked_style_patches(feat: torch.Tensor, mask: torch.Tensor, params: TransferParams) -> StylePatches:
    """Style patches whose centre lies in ``mask`` (> 0.5): the style's skin (or face),
    so its hair, background and any warp artefact never become texture sources."""
    sp = style_patches(feat, params.patch_size, params.style_stride)
    h, w = feat.shape[-2:]
    k = params.patch_size
    m = _resize_level(mask, (h, w))[0, 0]
    ys = _grid(h, k, params.style_stride) + k // 2
    xs = _grid(w, k, params.style_stride) + k // 2
    vals = m[ys][:, xs].reshape(-1)
    keep = vals > 0.5
    if int(keep.sum()) < MIN_STYLE_PATCHES:
        # a coarse level can hold fewer skin centres than that: the patches most inside the skin
        # (all of them had let the style's hair and background be sources there, FRL 004 <- 005)
        if not bool((vals > 0).any()):
            return sp
        n = min(MIN_STYLE_PATCHES, int((vals > 0).sum()))
        keep = torch.zeros_like(keep)
        keep[torch.argsort(vals, descending=True, stable=True)[:n]] = True
    return StylePatches(sp.unit[keep], sp.norm[keep], sp.channels, sp.size)


class _LevelLoss:
    """Weighted loss terms of one resolution level (Eqs. 2, 3, 4, 6)."""

    def __init__(self, builder: "_LossBuilder", shape):
        p = builder.params
        self.p = p
        self.net = builder.texture_net
        self.struct_net = builder.structure_net
        c = _resize_level(builder.content, shape)
        s = _resize_level(builder.style, shape)
        self.prior = _resize_level(builder.prior, shape) if builder.prior is not None else None
        self.norms: dict[str, float] | None = None
        with torch.no_grad():
            tex_layers = list(dict.fromkeys(p.mrf_layers + p.style_layers))
            fs = self._transform(_features(self.net, s, tex_layers) if tex_layers else {})
            fc = _features(self.net, c, p.content_layers) if p.content_layers else {}
            if builder.style_mask is not None:
                sm = _resize_level(builder.style_mask, shape)
                self.patches = {l: _masked_style_patches(fs[l], sm, p) for l in p.mrf_layers}
            else:
                self.patches = {l: style_patches(fs[l], p.patch_size, p.style_stride) for l in p.mrf_layers}
            self.target_w = {}
            if builder.target_mask is not None:  # texture loss only where the content may change
                tm = _resize_level(builder.target_mask, shape)
                self.target_w = {l: _resize_level(tm, tuple(fs[l].shape[-2:]))[0, 0] for l in p.mrf_layers}
            self.grams = {l: gram_matrix(fs[l]) for l in p.style_layers}
            self.content_t = {l: fc[l] for l in p.content_layers}
            self.content_ms = {l: float(fc[l].square().mean()) + 1e-12 for l in p.content_layers}
            self.chip_m = None
            if p.structure_weight:
                from ..nets.chip import face_chip_matrix, face_chip_tensor

                sx, sy = shape[1] / builder.shape[1], shape[0] / builder.shape[0]
                pts = (builder.points + 0.5) * [sx, sy] - 0.5
                self.chip_m = face_chip_matrix(pts)
                self._chip = lambda x: face_chip_tensor(x, self.chip_m, 150)
                fsc = _features(self.struct_net, self._chip(c), p.structure_layers)
                self.struct_t = fsc
                self.struct_ms = {l: float(v.square().mean()) + 1e-12 for l, v in fsc.items()}
            self.tv_ref = float(tv_loss(c)) + 1e-12

    def _transform(self, feats: dict) -> dict:
        """SWAG's channel softmax on the texture layers (MRF and Gram), if asked for."""
        p = self.p
        if p.feature_transform != "softmax":
            return feats
        tex = set(p.mrf_layers + p.style_layers)
        return {k: (channel_softmax(v, p.feature_temperature) if k in tex else v) for k, v in feats.items()}

    def raw_terms(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        p = self.p
        xin = apply_facial_prior(x, self.prior) if (p.prior and self.prior is not None) else x
        layers = list(dict.fromkeys(p.mrf_layers + p.style_layers + p.content_layers))
        f = self._transform(_features(self.net, xin, layers) if layers else {})
        terms = {}
        for l in p.mrf_layers:  # Eq. 2
            terms[f"mrf:{l}"] = mrf_loss(f[l], self.patches[l], patch_size=p.patch_size,
                                         style_stride=p.style_stride, variant=p.mrf_variant,
                                         target_weight=self.target_w.get(l))
        for l in p.style_layers:  # Eq. 6, style term
            terms[f"gram:{l}"] = gram_loss(f[l], self.grams[l])
        for l in p.content_layers:  # Eq. 6/7, content term
            terms[f"content:{l}"] = (f[l] - self.content_t[l]).square().mean() / self.content_ms[l]
        if p.structure_weight:  # Eq. 3: Σ_i 1/(C_i H_i W_i) ‖δ_i(x_t) − δ_i(x_c)‖², relative to ‖δ_i(x_c)‖²
            fst = _features(self.struct_net, self._chip(xin), p.structure_layers)
            terms["structure"] = sum((fst[l] - self.struct_t[l]).square().mean() / self.struct_ms[l]
                                     for l in p.structure_layers)
        if p.tv_weight:  # Eq. 4
            terms["tv"] = tv_loss(x) / self.tv_ref
        return terms

    def __call__(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        p = self.p
        raw = self.raw_terms(x)
        if self.norms is None:  # value at the start of the level (MRF and Gram terms)
            self.norms = {k: (max(float(v.detach()), 1e-12) if p.normalize and k.split(":")[0] in ("mrf", "gram")
                              else 1.0) for k, v in raw.items()}
        weights = {"mrf": p.mrf_weight, "gram": p.style_weight, "content": p.content_weight,
                   "structure": p.structure_weight, "tv": p.tv_weight}
        return {k: v * (weights[k.split(":")[0]] / self.norms[k]) for k, v in raw.items()}


class _LossBuilder:
    def __init__(self, params, content, style, prior, style_mask, target_mask, points, device):
        self.params = params
        self.device = device
        self.shape = content.shape[:2]
        self.content = to_tensor(content, device)
        self.style = to_tensor(style, device)
        as_t = lambda m: None if m is None else torch.from_numpy(np.ascontiguousarray(m, np.float32))[None, None].to(device)  # noqa: E731
        self.prior = as_t(prior)
        self.style_mask = as_t(style_mask)
        self.target_mask = as_t(target_mask)
        self.points = np.asarray(points, np.float64)
        net = params.texture_net
        if net == "vgg19" and params.vgg19_weights == "random":
            net = "vgg19-random"
        needs_tex = bool(params.mrf_layers or params.style_layers or params.content_layers)
        self.texture_net = _texture_net(net, str(device), None if net == "vgg19-random" else params.vgg19_weights) \
            if needs_tex else None
        self.structure_net = _structure_net(str(device)) if params.structure_weight else None

    def __call__(self, level: int, scale: float, shape) -> _LevelLoss:
        return _LevelLoss(self, shape)
