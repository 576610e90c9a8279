"""facetex: photo-realistic facial texture.

- FaceTex (Kaur, Zhang & Dana 2017): ``facetex.transfer(content, style, method="facetex")``.
- Persona (Suwajanakorn et al. 2015): ``facetex.persona`` — textures from a photo collection.

Images are numpy float32 RGB arrays in [0, 1], shape (H, W, 3); landmarks (N, 2) (x, y).
Heavy modules (torch, dlib) are imported on first use.
"""

from __future__ import annotations

import importlib

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
    "read_image": "io", "write_image": "io", "read_video": "io", "write_video": "io",
    "Face": "landmarks", "detect_faces": "landmarks", "detect_face": "landmarks", "face_mesh468": "landmarks",
    "transfer_with_info": "transfer",
    "landmark_error": "metrics", "texture_similarity": "metrics", "identity_distance": "metrics",
    "transfer_metrics": "metrics",
}
_SUBPACKAGES = ("io", "landmarks", "nets", "geometry", "transfer", "persona", "metrics", "bench")

__all__ = [
    "__version__", "FacetexError", "BadImageError", "BadInputError", "BadPersonaError", "BadVideoError",
    "MemoryBudgetError", "ModelNotFoundError", "NoFaceError", "OutputError", *_LAZY, *_SUBPACKAGES,
]


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    if name in _SUBPACKAGES:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'facetex' has no attribute {name!r}")
