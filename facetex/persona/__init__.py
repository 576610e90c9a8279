"""Persona textures from a photo collection ("What makes Tom Hanks look like Tom Hanks", Sec. 4-6):
collection, expression-dependent textures (global and regional weights), the average 3D face,
and puppet compositing into a driver's frame."""

from .._lazy import lazy_attributes as _lazy_attributes

#: public name -> the private module that defines it (imported on first use: importing one
#: submodule, e.g. the driver tracker in its own process, does not load them all)
_LAZY = {
    "Persona": "collection",
    "PersonaParams": "collection",
    "build_persona": "collection",
    "load_persona": "collection",
    "read_persona_header": "collection",
    "FACE_OVAL": "composite",
    "CompositeParams": "composite",
    "boundary_color_step": "composite",
    "composite_face": "composite",
    "feature_mask": "composite",
    "fit_sh_lighting": "composite",
    "inner_feather": "composite",
    "linear_to_srgb": "composite",
    "match_color_statistics": "composite",
    "mouth_interior": "composite",
    "poisson_blend": "composite",
    "polygon_mask": "composite",
    "relight": "composite",
    "sh_basis": "composite",
    "sh_shading": "composite",
    "srgb_to_linear": "composite",
    "METHODS": "texture",
    "STAGES": "texture",
    "WEIGHTS": "texture",
    "TextureParams": "texture",
    "average_face": "texture",
    "blend_textures": "texture",
    "prepare_persona": "texture",
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
    # compositing a puppet face into a driver frame (composite.py)
    "FACE_OVAL",
    "CompositeParams",
    "composite_face",
    "polygon_mask",
    "inner_feather",
    "feature_mask",
    "srgb_to_linear",
    "linear_to_srgb",
    "sh_basis",
    "fit_sh_lighting",
    "sh_shading",
    "relight",
    "match_color_statistics",
    "poisson_blend",
    "mouth_interior",
    "boundary_color_step",
]
