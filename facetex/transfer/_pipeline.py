"""The FaceTex transfer pipeline: landmarks → region → style pre-warp → masks → losses → L-BFGS.

Data flow (FaceTex §2.3 and §3.1)::

    content, style ──landmarks──> working region (face crop or whole image, long edge = size)
    style ──align_style_to_content (Beier–Neely morph + SIFT-flow refinement)──> style_w
    masks: facial prior × face region (gradient scaling, Sec. 2.2), face region (style patches)
    optimize_image(content_w, per-level losses) ──> paste back into the full content image
"""

from __future__ import annotations

import functools
import math
import time
import warnings
from dataclasses import asdict

import cv2
import numpy as np
import torch

from .._memory import available_memory
from ..errors import BadImageError, BadInputError, MemoryBudgetError
from ..io import to_float32
from .losses import (StylePatches, _grid, channel_softmax, gram_loss, gram_matrix, mrf_loss, mrf_memory_estimate,
                     style_patches, tv_loss)
from .methods import TransferParams, working_shape
from .methods import preset as make_preset
from .optimize import _resize as _resize_level
from .optimize import optimize_image, to_tensor
from .prior import apply_facial_prior

CROP_MARGIN = 0.12  # face crop margin around the face outline, × face width


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


# ---------------------------------------------------------------- regions
def face_crop_box(points68, shape, margin: float = CROP_MARGIN) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of the face (jaw + forehead arc) grown by ``margin`` × face width."""
    from ..geometry.masks import face_outline, face_width

    outline = face_outline(points68)
    pad = margin * face_width(points68)
    x0, y0 = np.floor(outline.min(0) - pad).astype(int)
    x1, y1 = np.ceil(outline.max(0) + pad).astype(int)
    h, w = shape[:2]
    return max(0, x0), max(0, y0), min(w, x1), min(h, y1)


def _resize(image: np.ndarray, size_wh: tuple[int, int]) -> np.ndarray:
    shrink = size_wh[0] < image.shape[1]
    interp = cv2.INTER_AREA if shrink else cv2.INTER_CUBIC
    return np.clip(cv2.resize(image, size_wh, interpolation=interp), 0.0, 1.0).astype(np.float32)


def _map_points(points, box, scale_xy):
    """Points of the full image → points of the (cropped, resized) region (pixel centres)."""
    p = np.asarray(points, np.float64)
    x0, y0 = box[0], box[1]
    return np.column_stack([(p[:, 0] - x0 + 0.5) * scale_xy[0] - 0.5, (p[:, 1] - y0 + 0.5) * scale_xy[1] - 0.5])


def _check_rgb(image, name: str, lazy: bool = False) -> np.ndarray:
    """``image`` as float32 RGB; with ``lazy`` an integer image over NATIVE_MAX_PIXELS stays as it
    is (its reduced part is made float, see :func:`_native_part`)."""
    a = np.asarray(image)
    if a.ndim != 3 or a.shape[2] != 3:
        raise BadImageError(f"{name} must be an (H, W, 3) RGB image, got shape {a.shape}")
    if not (lazy and (stays_integer(a) or stays_float(a))):
        a = to_float32(a)
    if min(a.shape[:2]) < 32:
        raise BadImageError(f"{name} of {a.shape[1]}x{a.shape[0]} px is too small: use at least 32 px")
    return a


def _init_image(init, content: np.ndarray) -> np.ndarray:
    """An ``init`` image (not "content" / "random") as float32 RGB of the content's size, checked."""
    if isinstance(init, str):
        raise BadInputError(f"init must be 'content', 'random' or an image array, not {init!r}")
    ini = _check_rgb(init, "init image")
    if ini.shape != content.shape:
        raise BadImageError(f"init image is {ini.shape[1]}x{ini.shape[0]} px, the content "
                            f"{content.shape[1]}x{content.shape[0]}: it must have the content's size")
    return ini


# ---------------------------------------------------------------- large images (issue 23)
#: Largest content or style image the pipeline works on as it is (1.5 MP; the paper's headshots
#: are 1000 px). Above it, the work is done on the face's neighbourhood (the crop box grown by
#: :data:`NATIVE_CONTEXT`, or the whole image with ``crop="image"``) reduced to at most this many
#: pixels, and only the change is brought back to the content's own pixels: a 36 MP photo took
#: minutes and GBs in the pre-warp and detail stages at full resolution (issue 23).
NATIVE_MAX_PIXELS = 1_500_000
NATIVE_CONTEXT = 0.1  # × the crop box's longer side: room for the skin mask and the face mesh


def stays_integer(image) -> bool:
    """Whether ``image`` is a uint8 / uint16 RGB array over :data:`NATIVE_MAX_PIXELS`, which the
    pipeline keeps as it is: only its reduced face region is made float (a 36 MP photo as float
    is 0.4 GB)."""
    return (isinstance(image, np.ndarray) and image.dtype in (np.uint8, np.uint16) and image.ndim == 3
            and image.shape[2] == 3 and image.shape[0] * image.shape[1] > NATIVE_MAX_PIXELS)


def stays_float(image) -> bool:
    """Whether ``image`` is a float RGB array over :data:`NATIVE_MAX_PIXELS`, which the pipeline
    keeps as it is, like :func:`stays_integer`: its reduced face region is made float32 and
    clipped to [0, 1] (a 6000 x 6000 float64 array is 0.8 GB, its float32 copy another 0.4 GB;
    issue 23). Its values must have passed :func:`facetex.io.check_float_pixels`."""
    return (isinstance(image, np.ndarray) and image.dtype.kind == "f" and image.ndim == 3
            and image.shape[2] == 3 and image.shape[0] * image.shape[1] > NATIVE_MAX_PIXELS)


def _clipped_float32(image: np.ndarray, copy: bool = False) -> np.ndarray:
    """A float image as float32 clipped to [0, 1], converted in row strips (no float64 or
    boolean temporaries of its size); the same values as ``np.clip(to_float32(image), 0, 1)``.
    Without ``copy`` a float32 image already in [0, 1] is returned as it is."""
    if not copy and image.dtype == np.float32 and (image.size == 0 or (image.min() >= 0 and image.max() <= 1)):
        return image
    out = np.empty(image.shape, np.float32)
    rows = max(1, (1 << 22) // max(1, image.size // max(1, image.shape[0])))
    for i in range(0, image.shape[0], rows):
        np.clip(image[i:i + rows], 0.0, 1.0, out=out[i:i + rows], casting="same_kind")
    return out


def detect_points68(image: np.ndarray, source=None) -> np.ndarray:
    """68 landmarks of the largest face; on an image over :data:`facetex.io.DETECT_MAX_PIXELS`
    found on a copy reduced to it, in the image's own pixels."""
    from ..io import DETECT_MAX_PIXELS
    from ..landmarks import detect_face

    h, w = image.shape[:2]
    if h * w <= DETECT_MAX_PIXELS:
        return detect_face(image, source=source).points68
    k = math.sqrt(DETECT_MAX_PIXELS / (h * w))
    if image.dtype.kind == "f":  # reduced from float32 in [0, 1], as when the caller's array was converted
        image = _clipped_float32(image)
    small = cv2.resize(image, (max(1, int(w * k)), max(1, int(h * k))), interpolation=cv2.INTER_AREA)
    to_full = (w / small.shape[1], h / small.shape[0])
    if small.dtype != np.uint8 and np.issubdtype(small.dtype, np.floating):
        # the detector's own uint8 conversion, made here: detect_face would first copy the float
        # image (as_image) and convert it with float temporaries of its size (issue 23)
        from ..landmarks import _as_uint8_rgb

        small = _as_uint8_rgb(np.clip(small, 0.0, 1.0, out=small))
    return _map_points(detect_face(small, source=source).points68, (0, 0), to_full)


def _native_part(image: np.ndarray, points68, crop: str):
    """(part box (x0, y0, x1, y1) of ``image``, the part reduced to at most NATIVE_MAX_PIXELS,
    its points, (sx, sy) = reduced size / part size) of an image over NATIVE_MAX_PIXELS."""
    H, W = image.shape[:2]
    if crop == "face":
        x0, y0, x1, y1 = face_crop_box(points68, image.shape)
        pad = math.ceil(NATIVE_CONTEXT * max(x1 - x0, y1 - y0))
        part = (max(0, x0 - pad), max(0, y0 - pad), min(W, x1 + pad), min(H, y1 + pad))
    else:
        part = (0, 0, W, H)
    pw, ph = part[2] - part[0], part[3] - part[1]
    k = min(1.0, math.sqrt(NATIVE_MAX_PIXELS / (pw * ph)))
    sub = image[part[1]:part[3], part[0]:part[2]]
    if sub.dtype.kind == "f":  # a float array kept as it is (stays_float): the part as float32 in [0, 1]
        sub = _clipped_float32(sub)
    if k < 1.0:  # reduced in the image's own type (a uint8 photo is not made float at full size)
        sub = cv2.resize(np.ascontiguousarray(sub), (max(32, int(pw * k)), max(32, int(ph * k))),
                         interpolation=cv2.INTER_AREA)
    sub = np.clip(to_float32(sub), 0.0, 1.0)  # a new array: the caller's image is never written
    sx, sy = sub.shape[1] / pw, sub.shape[0] / ph
    return part, sub, _map_points(points68, part, (sx, sy)), (sx, sy)


def _paste_change(content: np.ndarray, part, scale_xy, before: np.ndarray, after: np.ndarray, box_small,
                  rows: int = 256, in_place: bool = False) -> np.ndarray:
    """``content`` with the change ``after − before`` of its reduced ``part`` (non-zero inside
    ``box_small`` only) brought to the part's full resolution (bilinear, strip by strip), as
    float32 (``content`` may be uint8 / uint16). ``in_place``: a float32 ``content`` that is the
    pipeline's own (the API's converted copy of a caller's array) is written and returned
    instead of copied (issue 23: a 6000 x 6000 image is 0.4 GB as float32)."""
    if content.dtype.kind == "f" and not (in_place and content.dtype == np.float32):
        out = _clipped_float32(content, copy=True)  # a float array kept as it is: clipped like as_image
    else:
        out = to_float32(content)
        if np.shares_memory(out, content) and not (in_place and out is content):
            out = out.copy()
    sx, sy = scale_xy
    delta = (after - before).astype(np.float32)
    pw, ph = part[2] - part[0], part[3] - part[1]
    fx0, fy0 = max(0, int((box_small[0] - 1) / sx)), max(0, int((box_small[1] - 1) / sy))
    fx1, fy1 = min(pw, math.ceil((box_small[2] + 1) / sx)), min(ph, math.ceil((box_small[3] + 1) / sy))
    xs = ((np.arange(fx0, fx1, dtype=np.float64) + 0.5) * sx - 0.5).astype(np.float32)
    for r0 in range(fy0, fy1, rows):
        r1 = min(fy1, r0 + rows)
        ys = ((np.arange(r0, r1, dtype=np.float64) + 0.5) * sy - 0.5).astype(np.float32)
        mx, my = np.meshgrid(xs, ys)
        d = cv2.remap(delta, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        view = out[part[1] + r0:part[1] + r1, part[0] + fx0:part[0] + fx1]
        view += d
        np.clip(view, 0.0, 1.0, out=view)
    return out


def _full_box(part, scale_xy, box_small, shape) -> tuple[int, int, int, int]:
    sx, sy = scale_xy
    return (max(0, part[0] + int(box_small[0] / sx)), max(0, part[1] + int(box_small[1] / sy)),
            min(shape[1], part[0] + math.ceil(box_small[2] / sx)),
            min(shape[0], part[1] + math.ceil(box_small[3] / sy)))


def _transfer_reduced(content, style, cp, sp, params, init, callback, kwargs,
                      content_owned: bool = False) -> tuple[np.ndarray, dict]:
    """:func:`transfer_with_info` of a content or style over NATIVE_MAX_PIXELS (see there);
    ``content_owned``: the output is pasted into ``content`` itself (see :func:`_paste_change`)."""
    c_part, c_sub, c_pts, c_scale = (((0, 0, content.shape[1], content.shape[0]), content, cp, (1.0, 1.0))
                                     if content.shape[0] * content.shape[1] <= NATIVE_MAX_PIXELS
                                     else _native_part(content, cp, params.crop))
    s_sub, s_pts = style, sp
    if style.shape[0] * style.shape[1] > NATIVE_MAX_PIXELS:
        _, s_sub, s_pts, _ = _native_part(style, sp, params.crop)
    if not (isinstance(init, str) and init in ("content", "random")):
        ini = _init_image(init, content)[c_part[1]:c_part[3], c_part[0]:c_part[2]]
        init = ini if ini.shape == c_sub.shape else _resize(ini, (c_sub.shape[1], c_sub.shape[0]))
    wrapped = None
    if callback is not None:
        def wrapped(image, level, evaluation, full_image, box):
            callback(image=image, level=level, evaluation=evaluation,
                     full_image=_paste_change(content, c_part, c_scale, c_sub, full_image, box),
                     box=_full_box(c_part, c_scale, box, content.shape))
    for name, (big, sub) in {"content": (content, c_sub), "style": (style, s_sub)}.items():
        if sub is not big:
            warnings.warn(f"{name} image is {big.shape[1]}x{big.shape[0]} px: worked on "
                          f"{'its face region' if params.crop == 'face' else 'it'} at {sub.shape[1]}x{sub.shape[0]} "
                          f"(at most {NATIVE_MAX_PIXELS / 1e6:g} megapixels)"
                          + ("; the change is pasted at full resolution" if name == "content" else ""), stacklevel=3)
    out_sub, info = transfer_with_info(c_sub, s_sub, content_points=c_pts, style_points=s_pts, init=init,
                                       callback=wrapped, **kwargs)
    box_small = info["region_box"]
    out = out_sub if c_sub is content else _paste_change(content, c_part, c_scale, c_sub, out_sub, box_small,
                                                         in_place=content_owned)
    info["region_box"] = list(map(int, _full_box(c_part, c_scale, box_small, content.shape)))
    info["reduced"] = {"content_part": list(map(int, c_part)), "content_scale": [float(v) for v in c_scale],
                       "content_work_shape": list(c_sub.shape[:2]), "style_work_shape": list(s_sub.shape[:2]),
                       "max_pixels": NATIVE_MAX_PIXELS}
    return out, info


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
        p, dev = builder.params, builder.device
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


# ---------------------------------------------------------------- masks and pre-warp
def _face_mesh(image, points68):
    """MediaPipe mesh of the face at ``points68``, or None when the mesh finds no face there
    (the skin mask then falls back to the landmark outline)."""
    from ..errors import FacetexError
    from ..landmarks import face_mesh468

    try:
        return face_mesh468(image, points68)
    except FacetexError:
        return None


def _crop_map_energies(style, style_map, face_width_style, dparams):
    """The style's band energies (detail stage) computed on the part of the style the map
    reads from, then carried into the content frame through the map."""
    from ..geometry.morph import remap
    from .detail import style_band_energies

    h, w = style.shape[:2]
    pad = int(np.ceil(6 * max(dparams.sigmas) * face_width_style / 330.0)) + 4
    x0 = int(max(0, np.floor(style_map[..., 0].min()) - pad))
    x1 = int(min(w, np.ceil(style_map[..., 0].max()) + pad + 1))
    y0 = int(max(0, np.floor(style_map[..., 1].min()) - pad))
    y1 = int(min(h, np.ceil(style_map[..., 1].max()) + pad + 1))
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    energies = style_band_energies(style[y0:y1, x0:x1], face_width=face_width_style, params=dparams)
    shifted = (style_map - np.array([x0, y0], np.float32)).astype(np.float32)
    return [remap(e, shifted, border="replicate") for e in energies]


# ---------------------------------------------------------------- public API
def transfer_with_info(content, style, *, method: str = "facetex", preset: str = "default", seed: int = 0, device: str = "cpu", progress=None,
                       callback=None, save_every: int | None = None, content_points=None, style_points=None,
                       content_source=None, style_source=None, max_memory: int | None = None,
                       init="content", _content_owned: bool = False, **options) -> tuple[np.ndarray, dict]:
    """Transfer the skin texture of ``style`` onto ``content`` (FaceTex, or a baseline).

    ``content``/``style``: (H, W, 3) RGB, float in [0, 1] or uint8. ``method``: "facetex"
    (Eq. 5), "mrf" (Eq. 7) or "gatys" (Eq. 6); ``preset``: "default" or "paper"; any
    :class:`TransferParams` field may be overridden as a keyword (``size``, ``iters``,
    ``texture_net``, ``structure_weight`` …). Returns the output at the content's size and
    an info dict (parameters, timings, per-level loss terms, pre-warp folds, and under
    ``"images"`` the working-region images: content, pre-warped style at native and working
    resolution, skin masks, the optimiser's output). ``progress(n=1, level=, loss=, terms=)`` is
    called per loss evaluation; ``callback(image=, level=, evaluation=, full_image=, box=)``
    every ``save_every`` evaluations and after each level: ``image`` is the working region at
    the level's size, ``full_image`` the full-size picture of that step (pasted as the output
    is, before the detail stage), ``box`` the region in the content.
    ``init``: where the optimisation starts — "content" (FaceTex §2.3), "random" (uniform
    noise in [0, 1], seeded, in the pixels that may change), or an (H, W, 3) image of the
    content's size.
    A content or style over :data:`NATIVE_MAX_PIXELS` is worked on around its face, reduced to
    that many pixels, and the change is pasted into the content at full resolution (a warning
    says so; ``info["reduced"]`` records it).
    ``_content_owned`` (the public API's): ``content`` is a float32 copy made for this call, and
    a large one becomes the output (the change pasted into it) instead of being copied again.
    Raises NoFaceError (naming ``*_source``), MemoryBudgetError above ``max_memory`` bytes.
    """
    from .. import __version__

    t_start = time.perf_counter()
    texture_net = options.pop("texture_net", None)
    base = make_preset(method, preset, texture_net)
    params = base.with_options(**options)
    content = _check_rgb(content, f"content image{'' if content_source is None else ' ' + str(content_source)}",
                         lazy=True)
    style = _check_rgb(style, f"style image{'' if style_source is None else ' ' + str(style_source)}", lazy=True)
    timings = {}
    t0 = time.perf_counter()
    cp = detect_points68(content, content_source) if content_points is None else np.asarray(content_points, float)
    sp = detect_points68(style, style_source) if style_points is None else np.asarray(style_points, float)
    timings["landmarks_s"] = time.perf_counter() - t0
    if max(content.shape[0] * content.shape[1], style.shape[0] * style.shape[1]) > NATIVE_MAX_PIXELS:
        kwargs = dict(method=method, preset=preset, seed=seed, device=device, progress=progress, save_every=save_every,
                      content_source=content_source, style_source=style_source, max_memory=max_memory,
                      **({} if texture_net is None else {"texture_net": texture_net}), **options)
        out, info = _transfer_reduced(content, style, cp, sp, params, init, callback, kwargs,
                                      content_owned=_content_owned)
        info["timings"]["landmarks_s"] += timings["landmarks_s"]
        info["timings"]["total_s"] = time.perf_counter() - t_start
        return out, info

    # working region
    H, W = content.shape[:2]
    box = face_crop_box(cp, content.shape) if params.crop == "face" else (0, 0, W, H)
    region = content[box[1]:box[3], box[0]:box[2]]
    rh, rw = region.shape[:2]
    wh = working_shape(rh, rw, params.size)
    if params.size < params.min_size((rh, rw)):  # an elongated region: its short side is too small
        need = params.min_size((rh, rw))
        raise BadInputError(f"the {'face' if params.crop == 'face' else 'image'} region of {rw}x{rh} px is "
                            f"{wh[1]}x{wh[0]} px at size {params.size}, too narrow for {params.patch_size}-px "
                            "MRF patches at the coarsest level: "
                            + (f"use --size {need} or more" if need <= 4096 else "crop it less elongated"),
                            path=content_source)
    scale_xy = (wh[1] / rw, wh[0] / rh)
    content_w = _resize(region, (wh[1], wh[0]))
    cpr = cp - [box[0], box[1]]
    cpw = _map_points(cp, box, scale_xy)
    warn = []
    if max(rh, rw) < params.size:
        warn.append(f"content {'face' if params.crop == 'face' else 'image'} region is "
                    f"{rw}x{rh} px: upscaled to {wh[1]}x{wh[0]} (pass a smaller --size)")
    sbox = face_crop_box(sp, style.shape) if params.crop == "face" else (0, 0, style.shape[1], style.shape[0])
    if max(sbox[2] - sbox[0], sbox[3] - sbox[1]) < params.size:
        warn.append(f"style {'face' if params.crop == 'face' else 'image'} region is "
                    f"{sbox[2] - sbox[0]}x{sbox[3] - sbox[1]} px, smaller than the working size {params.size} px: "
                    "its texture is upscaled")
    for w_ in warn:
        warnings.warn(w_, stacklevel=2)

    budget = default_max_memory() if max_memory is None else int(max_memory)
    need = estimate_transfer_memory(params, wh)
    if need > budget:
        raise MemoryBudgetError(f"this transfer needs about {need / 2**30:.1f} GiB at {wh[1]}x{wh[0]} px, over the "
                                f"{budget / 2**30:.1f} GiB budget: use a smaller --size or raise --max-memory")

    # style pre-warp onto the content region's geometry, at the region's own resolution (Sec. 2.3)
    t0 = time.perf_counter()
    from ..geometry.masks import face_mask, face_width, prior_mask
    from ..geometry.morph import remap

    folds, style_map = 0, None
    if params.align:
        from ..geometry.style_align import align_style_to_content

        al = align_style_to_content(style, region, style_points=sp, content_points=cpr, method=params.align,
                                    refine=params.align_refine, frame=params.align_frame, interpolation="lanczos")
        style_native, style_map, folds = al.image, al.map_xy, al.folds
    else:
        sreg = style[sbox[1]:sbox[3], sbox[0]:sbox[2]]
        style_native = _resize(sreg, (rw, rh))
    style_native = np.clip(style_native, 0, 1).astype(np.float32)
    style_w = _resize(style_native, (wh[1], wh[0]))
    timings["align_s"] = time.perf_counter() - t0

    # masks: skin of both faces (content region frame), facial prior, face region
    t0 = time.perf_counter()
    needs_skin = params.constraint == "skin" or params.style_region == "skin" or params.target_region == "skin" \
        or params.detail or params.keep_shading or params.marks != "off"
    skin_c = skin_s = None
    if needs_skin:
        from ..geometry.segment import skin_mask

        skin_c = skin_mask(content, cp, mesh=_face_mesh(content, cp))[box[1]:box[3], box[0]:box[2]]
        # the style lends texture only from bare skin: no hair, beard or highlights (issue 22)
        skin_style_own = skin_mask(style, sp, mesh=_face_mesh(style, sp), source=True)
        if style_map is not None:
            skin_s = remap(skin_style_own, style_map, border="constant")
        else:
            skin_s = _resize(np.repeat(skin_style_own[sbox[1]:sbox[3], sbox[0]:sbox[2], None], 3, 2), (rw, rh))[..., 0]
        skin_s = np.clip(skin_s, 0, 1).astype(np.float32)
    down = lambda m: None if m is None else cv2.resize(m, (wh[1], wh[0]), interpolation=cv2.INTER_AREA)  # noqa: E731
    skin_cw, skin_sw = down(skin_c), down(skin_s)
    face = face_mask(cpw, wh)
    prior = prior_mask(cpw, wh) if params.prior else None
    style_mask = {"skin": None if skin_sw is None else skin_sw * (skin_cw > 0.05), "face": face,
                  "image": None}[params.style_region]
    target_mask = None
    if params.target_region == "skin":
        target_mask = skin_cw
    elif params.target_region == "face":  # every patch that can change: the face grown by the features' reach
        r = max(1, int(round(0.05 * max(wh))))
        target_mask = cv2.dilate((face > 0.01).astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8))
        target_mask = target_mask.astype(np.float32)
    change_mask = None
    if params.constraint == "skin":
        cm = torch.from_numpy(np.ascontiguousarray(skin_cw))[None, None].to(device)
        change_mask = lambda shape: _resize_level(cm, shape)  # noqa: E731
    timings["masks_s"] = time.perf_counter() - t0

    # optimisation (Eq. 5 / 6 / 7), multi-resolution L-BFGS
    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)
    start = None
    if isinstance(init, str) and init == "random":
        start = np.random.default_rng(seed).uniform(0.0, 1.0, content_w.shape).astype(np.float32)
    elif not (isinstance(init, str) and init == "content"):
        start = _resize(_init_image(init, content)[box[1]:box[3], box[0]:box[2]], (wh[1], wh[0]))
    builder = _LossBuilder(params, content_w, style_w, prior, style_mask, target_mask, cpw, device)
    user_callback = callback
    if user_callback is not None:
        def callback(image, level, evaluation):  # noqa: F811 — adds the full-size picture of the step
            full = _paste(content, region, box, content_w, _resize(image, (wh[1], wh[0])), skin_c, params)
            user_callback(image=image, level=level, evaluation=evaluation, full_image=full, box=box)
    out_w, info = optimize_image(content_w, builder, levels=params.levels, iters=params.iters,
                                 lbfgs_history=params.lbfgs_history, line_search=params.line_search,
                                 seed=seed, device=device, progress=progress, callback=callback,
                                 save_every=save_every, level_init=params.level_init, change_mask=change_mask,
                                 start=start, eval_budget=params.eval_budget, converge=params.converge)
    timings["optimize_s"] = info["seconds"]

    # back to the region's full resolution: paste the *change*, so the content's own detail
    # above the working resolution survives instead of being blurred by the resampling
    t0 = time.perf_counter()
    out_region = _paste_region(region, content_w, out_w, skin_c, params)
    optimised_region = out_region
    detail_info = None
    if params.detail:
        from .detail import DetailParams, transfer_skin_detail

        dparams = DetailParams(strength=params.detail_strength)
        energies = None
        if style_map is not None:
            energies = _crop_map_energies(style, style_map, face_width(sp), dparams)
        from ..geometry.segment import beard_zone_mask

        # the content's upper lip and chin keep their own fine detail: the style's pores
        # copied there read as stubble specks on a clean-shaven face (issue 22)
        out_region, detail_info = transfer_skin_detail(out_region, style_native, skin_c, skin_s,
                                                       style_energy=energies, face_width=face_width(cpr),
                                                       params=dparams, own_zone=beard_zone_mask(cpr, (rh, rw)),
                                                       own_detail=region, return_info=True)
    timings["detail_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    marks_info = None
    if params.marks != "off":
        from .marks import transfer_marks

        out_region, found = transfer_marks(out_region, region, style_native, skin_c, skin_s, mode=params.marks,
                                           face_width=face_width(cpr), return_info=True)
        marks_info = {"mode": params.marks, "content": int(len(found["content"])), "style": int(len(found["style"]))}
    if params.keep_shading:
        from .colour import eye_distance, keep_content_shading

        ed = eye_distance(cpr)
        out_region = keep_content_shading(out_region, region, skin_c, params.shading_sigma * ed,
                                          colour_sigma=params.colour_sigma * ed)
    timings["finish_s"] = time.perf_counter() - t0
    out = _compose(content, region, box, out_region, params)
    timings["total_s"] = time.perf_counter() - t_start
    info = {
        "method": params.method, "preset": params.preset, "params": _jsonable(asdict(params)),
        "seed": seed, "device": str(device), "init": init if isinstance(init, str) else "image",
        "timings": timings, "levels": info["levels"],
        "optimizer": {k: info[k] for k in ("optimizer", "line_search", "lbfgs_history", "clamp")},
        "region_box": list(map(int, box)), "working_shape": list(wh), "warnings": warn,
        "prewarp_folds": int(folds), "detail": detail_info, "marks": marks_info,
        "memory_estimate_bytes": need, "versions": _versions(__version__),
        "images": {"content_w": content_w, "style_w": style_w, "output_w": out_w, "prior": prior, "face": face,
                   "region": region, "style_native": style_native, "skin_content": skin_c, "skin_style": skin_s,
                   "optimised_region": optimised_region, "output_region": out_region},
    }
    return out.astype(np.float32), info


def _paste_region(region, content_w, out_w, skin_c, params) -> np.ndarray:
    """The region at its full resolution with the optimiser's *change* pasted in: the
    content's own detail above the working resolution survives instead of being blurred
    by the resampling; with the skin constraint nothing changes outside the skin."""
    rh, rw = region.shape[:2]
    delta = cv2.resize(out_w - content_w, (rw, rh), interpolation=cv2.INTER_CUBIC)
    if params.constraint == "skin":
        delta *= (skin_c > 0)[..., None]  # exactly nothing outside the skin (cubic rings 1–2 px)
    return np.clip(region + delta, 0.0, 1.0)


def _compose(content, region, box, out_region, params) -> np.ndarray:
    """The full image with the region replaced (feathered at inner crop edges when the whole
    crop may change)."""
    out = content.copy()
    rh, rw = region.shape[:2]
    if params.crop == "face" and params.constraint != "skin":
        alpha = _edge_feather((rh, rw), box, content.shape[:2])
        out[box[1]:box[3], box[0]:box[2]] = alpha[..., None] * out_region + (1 - alpha[..., None]) * region
    else:
        out[box[1]:box[3], box[0]:box[2]] = out_region
    return out


def _paste(content, region, box, content_w, out_w, skin_c, params) -> np.ndarray:
    return _compose(content, region, box, _paste_region(region, content_w, out_w, skin_c, params), params)


def _edge_feather(shape, box, full_shape, frac: float = 0.08) -> np.ndarray:
    """Blend weight of a pasted region: 1 inside, ramping to 0 at crop edges that lie inside
    the image (edges on the image border need no blending)."""
    h, w = shape
    r = max(2, int(frac * min(h, w)))
    y = np.ones(h, np.float32)
    x = np.ones(w, np.float32)
    ramp = (np.arange(r, dtype=np.float32) + 0.5) / r
    if box[1] > 0:
        y[:r] = np.minimum(y[:r], ramp)
    if box[3] < full_shape[0]:
        y[-r:] = np.minimum(y[-r:], ramp[::-1])
    if box[0] > 0:
        x[:r] = np.minimum(x[:r], ramp)
    if box[2] < full_shape[1]:
        x[-r:] = np.minimum(x[-r:], ramp[::-1])
    return np.outer(y, x)


def _jsonable(d):
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}


def _versions(version: str) -> dict:
    import platform

    return {"facetex": version, "torch": torch.__version__, "numpy": np.__version__, "opencv": cv2.__version__,
            "python": platform.python_version()}


def transfer(content, style, *, method: str = "facetex", **options) -> np.ndarray:
    """:func:`transfer_with_info` returning only the output image (H, W, 3) float32."""
    return transfer_with_info(content, style, method=method, **options)[0]
