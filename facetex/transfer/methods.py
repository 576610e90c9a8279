"""Method presets: FaceTex (Eq. 5), MRF-CNN (Eq. 7) and Gatys neural style (Eq. 6).

One frozen dataclass holds every weight, layer and schedule of a run; :func:`preset`
builds it from (method, preset, texture network). Two presets:

- ``paper``: the paper's schedule — whole image at 1000 px long edge, 3 levels × 200
  L-BFGS iterations (Gatys: 1000 iterations at full size), the paper's layers when the
  texture network is VGG-19.
- ``default``: the best quality we measured in under a minute on a 2-core CPU — a face
  crop (forehead to chin plus margin: FaceTex works on tight head portraits, and hair and
  background caused most artifacts in our measurements) at 384 px, 3 levels × 100
  iterations (the authors' CNNMRF defaults), EfficientNet-Lite0 texture features; for
  FaceTex also: only the content's skin may change (a hard constraint in place of the
  gradient-scaling prior, see prior.py), style patches come only from the style's skin,
  the texture loss counts only the content's skin, and a native-resolution detail stage
  (detail.py) puts the style's own pores and fine wrinkles at the output's resolution
  (docs/facetex-fidelity.md has the measurements behind each choice).

Loss weights are *normalised* in both presets (``normalize=True``): each MRF and Gram
term is divided by its value at the start of its level, content and structure terms by
the mean square of their target features, TV by the content image's TV. The paper's raw
weights (λ_c = 5, λ_s = 100, λ_TV = 1e-3; CNNMRF's 1e-4 / 2e1 / 1e-3) are tied to
Caffe-VGG feature scales and 0–255 BGR pixels and do not carry over to other networks
(findings: "raw CNNMRF weights do not carry over between networks"). The paper's ratio
λ_s/λ_c = 20 is kept for Gatys as the ratio of the normalised weights' *effects* only
approximately; ``normalize=False`` runs the raw sums with whatever weights you give.

The texture network, its layers, the structure layers and the weights were chosen by
measurement on FRL London pairs (``benchmarks/transfer_choices.py``, docs/texture-nets.md):
EfficientNet-Lite0 blocks 2 + 4 (content block 7); structure on FaceRecognitionNet
level2 + level3, weight 1; texture weight 2 for FaceTex, 1 for MRF-CNN; Gram weight 0.1 for
Gatys (with 1 it moved more texture than MRF-CNN and changed the landmarks more than
FaceTex, contrary to Table 1); 384 px × 3 levels × 100 iterations ran in 46 s on the idle
2-core machine (512 px: 72 s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from ..errors import BadInputError

METHODS = ("facetex", "mrf", "gatys")
PRESETS = ("default", "paper", "preview")
TEXTURE_NETS = ("effnet-lite0", "vgg19", "face-resnet")

# Layer roles per texture network: MRF texture layers, content layer, Gram style layers.
# VGG-19 names are the paper's; the others match VGG's strides (relu3_1/relu4_1 = 4 and 8,
# relu4_2 = 16). EfficientNet-Lite0 block2+block4 kept identity and landmarks best of the
# sets we measured (block1+block4, block4 alone; face-resnet pool1/level1+level2: ghost
# features and colour blotches; random VGG-19: chroma noise, 3x slower): docs/texture-nets.md.
NET_LAYERS = {
    "vgg19": {"mrf": ("relu3_1", "relu4_1"), "content": ("relu4_2",),
              "style": ("relu1_1", "relu2_1", "relu3_1", "relu4_1", "relu5_1")},
    "effnet-lite0": {"mrf": ("block2", "block4"), "content": ("block7",),
                     "style": ("stem", "block2", "block4", "block7", "block14")},
    "face-resnet": {"mrf": ("pool1", "level2"), "content": ("level3",),
                    "style": ("conv1", "level1", "level2", "level3", "level4")},
}
# FaceRecognitionNet layers for the facial-structure loss (Eq. 3), the stand-in for
# VGG-Face relu4_2: mid-level maps on the 150 px face chip (17² and 8²); at weight 1 they
# kept landmarks and identity best of level1..level4 and pairs of them (docs/texture-nets.md).
STRUCTURE_LAYERS = ("level2", "level3")
#: side of the deepest MRF layer's feature map (stride 8 in every network) for an input side n,
#: measured: "same" padding rounds up, VGG's pooling down, dlib's unpadded convolutions lose 9 px
#: (a lower bound, exact at most sides)
MRF_FEATURE_SIDE = {"effnet-lite0": lambda n: -(-n // 8), "vgg19": lambda n: n // 8,
                    "vgg19-random": lambda n: n // 8, "face-resnet": lambda n: (n - 9) // 8}
PREVIEW_SIZE = 256  # px: the preview preset's working size
PREVIEW_ITERS = (12, 12, 12)


@dataclass(frozen=True)
class TransferParams:
    """Everything that defines a transfer run (recorded in the output's JSON sidecar)."""

    method: str = "facetex"
    preset: str = "default"
    texture_net: str = "effnet-lite0"
    size: int = 384  # long edge of the working region (px) at the finest level
    crop: str = "face"  # "face": work on a face crop and paste back; "image": whole image
    levels: int = 3
    iters: tuple[int, ...] = (100, 100, 100)
    # losses (weights are per term; see the module docstring on normalisation)
    mrf_layers: tuple[str, ...] = ()
    mrf_weight: float = 0.0
    mrf_variant: str = "paper"  # "paper" (Eq. 2) or "reference" (CNNMRF's code)
    patch_size: int = 3
    style_stride: int = 2
    style_region: str = "face"  # MRF style patches from: "skin" (the style's skin, warped), "face", "image"
    target_region: str = "image"  # texture loss over the "image", the "face" (all it can change) or the "skin"
    constraint: str | None = None  # "skin": x = c + m ⊙ z, only the content's skin can change
    content_layers: tuple[str, ...] = ()
    content_weight: float = 0.0
    style_layers: tuple[str, ...] = ()
    style_weight: float = 0.0
    structure_layers: tuple[str, ...] = ()
    structure_weight: float = 0.0
    tv_weight: float = 0.0
    prior: bool = False  # facial prior gradient mask (Sec. 2.2)
    normalize: bool = True
    align: str | None = "beier-neely"  # style → content pre-warp (Sec. 2.3), None to skip
    align_refine: str | None = "sift-flow"
    align_frame: str = "similarity"  # pre-warp frame pinning (see geometry.style_align.align_style_to_content)
    feature_transform: str | None = None  # "softmax": SWAG's channel softmax on texture features
    feature_temperature: float = 1.0
    detail: bool = False  # native-resolution skin detail stage (transfer/detail.py)
    detail_strength: float = 1.0
    keep_shading: bool = False  # the content keeps its low-frequency colour and shading in the skin (colour.py)
    shading_sigma: float = 0.15  # the shading step's low-pass σ of the luminance, × the eye distance (colour.py)
    colour_sigma: float = 0.05  # … and of the chroma (colour cast)
    marks: str = "off"  # "content": keep the content's moles/spots; "style": the style's (marks.py); "off"
    lbfgs_history: int = 25
    eval_budget: float = 2.0  # loss evaluations per level ≤ this × iterations (strong-Wolfe uses 1–4 per iteration)
    converge: tuple[int, float] | None = None  # (k, rtol): a level ends when its loss fell < rtol in k iterations
    level_init: str = "residual"  # "upsample" is CNNMRF's (see optimize_image)
    line_search: str | None = "strong_wolfe"
    vgg19_weights: str | None = None
    extra: dict = field(default_factory=dict)

    def with_options(self, **options) -> "TransferParams":
        """A copy with some fields replaced; unknown names are an error."""
        names = set(self.__dataclass_fields__)
        unknown = sorted(set(options) - names)
        if unknown:
            raise BadInputError(f"unknown transfer option(s) {unknown}; valid: {sorted(names)}")
        if "iters" in options and options["iters"] is not None:
            iters = options["iters"]
            iters = (int(iters),) if isinstance(iters, int) else tuple(int(i) for i in iters)
            options["iters"] = iters
            options.setdefault("levels", len(iters))
        p = replace(self, **{k: v for k, v in options.items() if v is not None})
        if len(p.iters) == 1 and p.levels > 1:
            p = replace(p, iters=p.iters * p.levels)
        p.validate()
        return p

    def min_size(self, region: tuple[int, int] = (1, 1)) -> int:
        """Smallest ``size`` at which a working region of ``region``'s (h, w) proportions still
        holds one MRF patch in the deepest MRF layer at the coarsest level (:data:`MRF_FEATURE_SIDE`;
        ``size`` 32 without the MRF term, 4097 when none up to 4096 does)."""
        if not (self.mrf_weight and self.mrf_layers):
            return 32
        coarsest = 2.0 ** -(max(1, self.levels) - 1)  # optimize.level_shapes' first scale
        feature_side = MRF_FEATURE_SIDE.get(self.texture_net, lambda n: (n - 9) // 8)
        for size in range(32, 4097):
            side = math.ceil(min(working_shape(*region, size)) * coarsest)
            if feature_side(side) >= self.patch_size:
                return size
        return 4097

    def validate(self) -> None:
        if self.method not in METHODS:
            raise BadInputError(f"unknown method {self.method!r}: use one of {', '.join(METHODS)}")
        if self.texture_net not in TEXTURE_NETS:
            raise BadInputError(f"unknown texture network {self.texture_net!r}: use one of {', '.join(TEXTURE_NETS)}")
        if self.crop not in ("face", "image"):
            raise BadInputError(f"crop must be 'face' or 'image', not {self.crop!r}")
        if len(self.iters) != self.levels:
            raise BadInputError(f"{len(self.iters)} iteration counts for {self.levels} levels")
        if not 32 <= self.size <= 4096:
            raise BadInputError(f"size {self.size} px is out of range 32..4096")
        if self.size < self.min_size():  # fails at the first level otherwise, after the set-up
            raise BadInputError(f"size {self.size} px is too small for {self.patch_size}-px MRF patches at "
                                f"{self.levels} levels: use --size {self.min_size()} or more")
        if self.style_region not in ("skin", "face", "image"):
            raise BadInputError(f"style_region must be 'skin', 'face' or 'image', not {self.style_region!r}")
        if self.target_region not in ("skin", "face", "image"):
            raise BadInputError(f"target_region must be 'skin', 'face' or 'image', not {self.target_region!r}")
        if self.constraint not in (None, "skin"):
            raise BadInputError(f"constraint must be None or 'skin', not {self.constraint!r}")
        if self.feature_transform not in (None, "softmax"):
            raise BadInputError(f"feature_transform must be None or 'softmax', not {self.feature_transform!r}")
        if not self.feature_temperature > 0:
            raise BadInputError(f"feature_temperature must be > 0, got {self.feature_temperature}")
        if self.converge is not None and (len(self.converge) != 2 or int(self.converge[0]) < 1
                                          or not float(self.converge[1]) >= 0):
            raise BadInputError(f"converge must be (iterations >= 1, relative tolerance >= 0), got {self.converge!r}")
        if self.marks not in ("off", "content", "style"):
            raise BadInputError(f"marks must be 'content', 'style' or 'off', not {self.marks!r}")
        for name in ("shading_sigma", "colour_sigma"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise BadInputError(f"{name} must be in (0, 1] (× the eye distance), got {getattr(self, name)}")
        if not 0.0 <= self.detail_strength <= 2.0:
            raise BadInputError(f"detail_strength must be in [0, 2], got {self.detail_strength}")


def working_shape(h: int, w: int, size: int) -> tuple[int, int]:
    """(h, w) of a working region of (h, w) px scaled to a long edge of ``size`` px (at least 8)."""
    s = size / max(h, w)
    return max(8, round(h * s)), max(8, round(w * s))


def preset(method: str = "facetex", name: str = "default", texture_net: str | None = None) -> TransferParams:
    """The parameters of ``method`` under preset ``name`` with the given texture network."""
    if method not in METHODS:
        raise BadInputError(f"unknown method {method!r}: use one of {', '.join(METHODS)}")
    if name not in PRESETS:
        raise BadInputError(f"unknown preset {name!r}: use one of {', '.join(PRESETS)}")
    net = texture_net or "effnet-lite0"
    if net not in TEXTURE_NETS:
        raise BadInputError(f"unknown texture network {net!r}: use one of {', '.join(TEXTURE_NETS)}")
    layers = NET_LAYERS[net]
    base = TransferParams(method=method, preset=name, texture_net=net)
    if name == "preview":
        # the default's steps at 256 px and a few iterations per level: a look in seconds
        # while choosing a style (issue 22: <= 5 s per 1000 px portrait on 2 cores)
        # (no optical-flow refinement of the pre-warp: the landmark morph is enough for a look)
        base = replace(base, size=PREVIEW_SIZE, iters=PREVIEW_ITERS, eval_budget=1.25, align_refine=None)
    elif name == "paper":
        # 200 iterations per level, or until the loss falls < 1 % in 20 iterations: on the
        # default preset's finest level (FRL 083 <- 005) that is ~100 iterations, and the next
        # 100 lowered the loss by 2.6 % more (docs/facetex-fidelity.md §5)
        base = replace(base, size=1000, crop="image", levels=3, iters=(200, 200, 200), converge=(20, 0.01))
    else:
        base = replace(base, eval_budget=1.25)  # torch's max_eval default: the speed budget holds
        # a level ends when its best loss fell < 2 % in 10 iterations (issue 22, speed: on the
        # finest level the loss fell 46, 7.8, 3.1, 1.7, 1.2 % per 20 evaluations, so it stops
        # after ~50 of its 100 iterations; at < 1 % FRL 004 <- 005 ran 60, 80, 80 iterations,
        # 262 evaluations, 22 % less CPU than 3 x 100: not enough for 20 s; docs/facetex-fidelity.md §6)
        base = replace(base, converge=(10, 0.02))
        # measured on 10 FRL pairs at 1000 px (benchmarks/geometry_align.py): optical-flow
        # refinement left 2.66 px landmark error vs 2.93 px for SIFT flow, at 1/7 of the time
        base = replace(base, align_refine="optical-flow")
    if method == "facetex":  # Eq. 5: texture + facial structure + TV, prior mask
        # texture 2 : structure 1 (docs/texture-nets.md): more texture than MRF-CNN, identity kept
        p = replace(base, mrf_layers=layers["mrf"], mrf_weight=2.0, structure_layers=STRUCTURE_LAYERS,
                    structure_weight=1.0, tv_weight=0.05, prior=True)
        if name == "paper":
            # the prior and face mask freeze everything outside the face (§3.1): texture patches
            # there cannot change, so they are not matched (same optimum, a fraction of the time)
            p = replace(p, target_region="face")
        if name in ("default", "preview"):
            # only the content's skin changes (hard constraint instead of the gradient-scaling
            # prior, which L-BFGS undoes), texture from the style's skin only, and the style's
            # own pore-level detail at native resolution (docs/facetex-fidelity.md)
            p = replace(p, prior=False, constraint="skin", style_region="skin", target_region="skin", detail=True)
            # detail, not lighting: the style brings texture, the content keeps its own colour,
            # shading and marks (issue 22)
            p = replace(p, keep_shading=True, marks="content")
    elif method == "mrf":  # Eq. 7: texture + content + TV
        p = replace(base, mrf_layers=layers["mrf"], mrf_weight=1.0, content_layers=layers["content"],
                    content_weight=0.3, tv_weight=0.05, style_region="image")
        if name == "paper":  # §3.1: "Three resolutions with 100 iterations each"
            p = replace(p, iters=(100, 100, 100))
    else:  # Eq. 6: content + Gram style + TV
        # Gram weight 0.1 of the content's (docs/texture-nets.md): Table 1's Neural Style keeps
        # the landmarks best and moves the least texture; at 1 it did neither on our data
        p = replace(base, content_layers=layers["content"], content_weight=1.0, style_layers=layers["style"],
                    style_weight=0.1, tv_weight=0.05, align=None, align_refine=None)
        if name == "paper":
            p = replace(p, levels=1, iters=(1000,))
    p.validate()
    return p
