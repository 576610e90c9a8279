"""Personas from a photo collection ("What makes Tom Hanks look like Tom Hanks", §5): the collection
(frontalized, aligned photos and their collection flow), the expression weights and the
expression-dependent textures. The puppetry that drives a persona with a video (§4, §6: shape,
driver, deformation, rendering, compositing) is :mod:`facetex.puppet`."""

from .._lazy import lazy_attributes as _lazy_attributes

#: public name -> the private module that defines it (imported on first use: importing one
#: submodule, e.g. the driver tracker in its own process, does not load them all)
_LAZY = {
    "Persona": "collection",
    "PersonaParams": "collection",
    "build_persona": "build",
    "load_persona": "collection",
    "read_persona_header": "collection",
    "METHODS": "params",
    "STAGES": "params",
    "WEIGHTS": "params",
    "TextureParams": "params",
    "average_face": "texture",
    "blend_textures": "texture",
    "prepare_persona": "stacks",
    "synthesize_texture": "texture",
}

__getattr__, __dir__ = _lazy_attributes(__name__, globals(), _LAZY)


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
