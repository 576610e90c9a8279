"""FaceTex identity-preserving facial texture transfer, with the Gatys and MRF-CNN baselines.

The entry points are the functions :func:`facetex.transfer` and
:func:`facetex.transfer_with_info` (also importable from here). This subpackage holds
the implementation: losses are pure functions in :mod:`.losses`, the gradient-scaling
prior in :mod:`.prior`, the multi-resolution L-BFGS loop in :mod:`.optimize`, the
presets in :mod:`.methods` and the pipeline in :mod:`._pipeline` (its working region in
:mod:`._regions`, what each resolution level evaluates in :mod:`._levels`).

``facetex.transfer`` (the attribute) is the function; reach this subpackage with import
statements: ``from facetex.transfer import mrf_loss``, ``import facetex.transfer.losses as
losses``. Its submodules, once imported, are also attributes of the function
(``facetex.transfer.losses``), so dotted imports with ``as`` work.
"""

import importlib as _importlib
import sys as _sys
import types as _types

# Names resolve on first use (PEP 562) so that ``facetex.transfer.methods`` (read by the CLI
# parser) does not import torch: a 3 s start-up cost for every other command.
_LAZY = {
    "facetex._memory": ("available_memory",),
    "._levels": ("default_max_memory", "estimate_transfer_memory"),
    "._regions": ("face_crop_box",),
    "facetex._api": ("transfer", "transfer_with_info", "transfer_step_image"),
    ".losses": ("content_loss", "gram_loss", "gram_matrix", "mrf_loss", "mrf_match", "structure_loss", "tv_loss"),
    ".methods": ("METHODS", "PRESETS", "TEXTURE_NETS", "TransferParams", "preset"),
    ".optimize": ("optimize_image",),
    ".prior": ("FacialPrior", "FacialPriorGrad", "apply_facial_prior"),
}
_WHERE = {name: mod for mod, names in _LAZY.items() for name in names}

__all__ = [
    "transfer", "transfer_with_info", "transfer_step_image", "TransferParams", "preset", "METHODS", "PRESETS", "TEXTURE_NETS",
    "estimate_transfer_memory", "available_memory", "default_max_memory", "face_crop_box",
    "mrf_loss", "mrf_match", "content_loss", "gram_matrix", "gram_loss", "structure_loss", "tv_loss",
    "optimize_image", "FacialPrior", "FacialPriorGrad", "apply_facial_prior",
]


def __getattr__(name):
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    where = _WHERE[name]
    value = getattr(_importlib.import_module(where, __name__ if where.startswith(".") else None), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _Subpackage(_types.ModuleType):
    """Mirrors every submodule the import system binds here (``losses``, ``_pipeline`` …) onto
    the public function :func:`facetex.transfer`, which is what ``facetex.transfer`` names:
    ``import facetex.transfer.losses as losses`` then finds the module."""

    def __setattr__(self, name, value):
        super().__setattr__(name, value)
        if isinstance(value, _types.ModuleType) and value.__name__ == f"{self.__name__}.{name}":
            from .._api import transfer

            setattr(transfer, name, value)


_sys.modules[__name__].__class__ = _Subpackage
