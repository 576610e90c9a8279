"""FaceTex identity-preserving facial texture transfer, with the Gatys and MRF-CNN baselines.

``facetex.transfer(content, style, method=...)`` — this module is callable — returns the
output image; :func:`transfer_with_info` also returns parameters, timings and losses.
Losses are pure functions in :mod:`.losses`, the gradient-scaling prior in :mod:`.prior`,
the multi-resolution L-BFGS loop in :mod:`.optimize` and the presets in :mod:`.methods`.
"""

import sys as _sys
import types as _types

from ._pipeline import (
    available_memory,
    default_max_memory,
    estimate_transfer_memory,
    face_crop_box,
    transfer,
    transfer_with_info,
)
from .losses import content_loss, gram_loss, gram_matrix, mrf_loss, mrf_match, structure_loss, tv_loss
from .methods import METHODS, PRESETS, TEXTURE_NETS, TransferParams, preset
from .optimize import optimize_image
from .prior import FacialPrior, FacialPriorGrad, apply_facial_prior

__all__ = [
    "transfer", "transfer_with_info", "TransferParams", "preset", "METHODS", "PRESETS", "TEXTURE_NETS",
    "estimate_transfer_memory", "available_memory", "default_max_memory", "face_crop_box",
    "mrf_loss", "mrf_match", "content_loss", "gram_matrix", "gram_loss", "structure_loss", "tv_loss",
    "optimize_image", "FacialPrior", "FacialPriorGrad", "apply_facial_prior",
]


class _CallableModule(_types.ModuleType):
    """Lets ``facetex.transfer(content, style, ...)`` call :func:`transfer` directly."""

    def __call__(self, content, style, **options):
        return transfer(content, style, **options)


_sys.modules[__name__].__class__ = _CallableModule
