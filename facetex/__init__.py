"""facetex: photo-realistic facial texture.

- FaceTex (Kaur, Zhang & Dana 2017): :func:`facetex.transfer` (``content, style, method="facetex"``)
  and :func:`facetex.transfer_with_info`.
- Persona (Suwajanakorn et al. 2015): :func:`facetex.build_persona`, :func:`facetex.persona_texture`,
  :func:`facetex.persona_average`, :func:`facetex.persona_mesh`, :func:`facetex.puppeteer`.

Images are numpy float32 RGB arrays in [0, 1], shape (H, W, 3); landmarks (N, 2) (x, y).
Functions also take image files and PIL images. Heavy modules (torch, dlib) are imported on
first use.

``facetex.transfer`` is a function. Its implementation subpackage keeps the name
``facetex.transfer`` for import statements (``from facetex.transfer import mrf_loss``,
``import facetex.transfer.losses as losses``): the import system's binding of the
subpackage onto this package is not applied, so the public name stays the function.
"""

from __future__ import annotations

import importlib
import sys
import types

__version__ = "0.1.0"

from .errors import (  # noqa: E402
    BadImageError,
    BadInputError,
    BadPersonaError,
    BadVideoError,
    FacetexError,
    MemoryBudgetError,
    ModelNotFoundError,
    NoFaceError,
    OutputError,
)

_LAZY = {
    "transfer": "_api", "transfer_with_info": "_api", "transfer_step_image": "_api", "as_image": "_api",
    "parse_iters": "_api", "build_persona": "_api", "load_persona": "_api", "persona_texture": "_api",
    "texture_params": "_api", "persona_average": "_api", "persona_mesh": "_api", "Mesh": "_api", "puppeteer": "_api",
    "read_image": "io", "write_image": "io", "read_video": "io", "write_video": "io",
    "Face": "landmarks", "detect_faces": "landmarks", "detect_face": "landmarks", "face_mesh468": "landmarks",
    "landmark_error": "metrics", "texture_similarity": "metrics", "identity_distance": "metrics",
    "transfer_metrics": "metrics",
}
_SUBPACKAGES = ("io", "landmarks", "nets", "geometry", "persona", "puppet", "metrics", "bench", "report")
#: public functions that share their name with a subpackage: the function wins the attribute
_FUNCTIONS_OVER_SUBPACKAGES = frozenset({"transfer"})

__all__ = [
    "__version__", "FacetexError", "BadImageError", "BadInputError", "BadPersonaError", "BadVideoError",
    "MemoryBudgetError", "ModelNotFoundError", "NoFaceError", "OutputError", *_LAZY, *_SUBPACKAGES,
]


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    if name in _SUBPACKAGES:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'facetex' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _Package(types.ModuleType):
    """The facetex package: after importing a subpackage the import system sets it as an
    attribute of its parent (``facetex.transfer = <module>``); for names that are public
    functions that binding is skipped, so ``facetex.transfer`` stays the function."""

    def __setattr__(self, name, value):
        if name in _FUNCTIONS_OVER_SUBPACKAGES and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
