"""facetex: photo-realistic facial texture (FaceTex transfer, Persona textures)."""

from __future__ import annotations

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

__all__ = [
    "__version__",
    "FacetexError",
    "BadImageError",
    "BadInputError",
    "BadPersonaError",
    "BadVideoError",
    "MemoryBudgetError",
    "ModelNotFoundError",
    "NoFaceError",
    "OutputError",
]
