"""Persona textures from a photo collection ("What makes Tom Hanks look like Tom Hanks", Sec. 5)."""

from .collection import Persona, PersonaParams, build_persona, load_persona, read_persona_header
from .texture import (
    METHODS,
    STAGES,
    WEIGHTS,
    TextureParams,
    average_face,
    blend_textures,
    prepare_persona,
    synthesize_texture,
)

__all__ = [
    "Persona",
    "PersonaParams",
    "build_persona",
    "load_persona",
    "read_persona_header",
    "TextureParams",
    "synthesize_texture",
    "blend_textures",
    "WEIGHTS",
    "average_face",
    "prepare_persona",
    "METHODS",
    "STAGES",
]
