"""FaceTex identity-preserving facial texture transfer, with the Gatys and MRF-CNN baselines.

``facetex.transfer(content, style, method=...)`` — this module is callable — returns the
output image; :func:`transfer_with_info` also returns parameters, timings and losses.
Losses are pure functions in :mod:`.losses`, the gradient-scaling prior in :mod:`.prior`,
the multi-resolution L-BFGS loop in :mod:`.optimize` and the presets in :mod:`.methods`.
"""

import importlib as _importlib
import sys as _sys
import types as _types

# Names resolve on first use (PEP 562) so that ``facetex.transfer.methods`` (read by the CLI
# parser) does not import torch: a 3 s start-up cost for every other command.
_LAZY = {
    "._pipeline": ("available_memory", "default_max_memory", "estimate_transfer_memory", "face_crop_box",
                   "transfer", "transfer_with_info"),
    ".losses": ("content_loss", "gram_loss", "gram_matrix", "mrf_loss", "mrf_match", "structure_loss", "tv_loss"),
    ".methods": ("METHODS", "PRESETS", "TEXTURE_NETS", "TransferParams", "preset"),
    ".optimize": ("optimize_image",),
    ".prior": ("FacialPrior", "FacialPriorGrad", "apply_facial_prior"),
}
_WHERE = {name: mod for mod, names in _LAZY.items() for name in names}

__all__ = [
    "transfer", "transfer_with_info", "TransferParams", "preset", "METHODS", "PRESETS", "TEXTURE_NETS",
    "estimate_transfer_memory", "available_memory", "default_max_memory", "face_crop_box",
    "mrf_loss", "mrf_match", "content_loss", "gram_matrix", "gram_loss", "structure_loss", "tv_loss",
    "optimize_image", "FacialPrior", "FacialPriorGrad", "apply_facial_prior",
]


def __getattr__(name):
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(_importlib.import_module(_WHERE[name], __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _CallableModule(_types.ModuleType):
    """Lets ``facetex.transfer(content, style, ...)`` call :func:`transfer` directly."""

    def __call__(self, content, style, **options):
        return __getattr__("transfer")(content, style, **options)


_sys.modules[__name__].__class__ = _CallableModule
