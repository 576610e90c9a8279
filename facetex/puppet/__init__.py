"""Puppetry ("What makes Tom Hanks look like Tom Hanks", §4 and §6): one person's persona driven by
another person's video. The data flow, one module each: the driver's tracking and motion
(:mod:`~facetex.puppet.driver`), the average 3D shapes (:mod:`~facetex.puppet.shape`) and their
correspondence (:mod:`~facetex.puppet.correspondence`), the deformation transfer
(:mod:`~facetex.puppet.deform`), the per-frame puppet (:mod:`~facetex.puppet.puppeteer`), its
rendering (:mod:`~facetex.puppet.render`) and its compositing into the driver's frame
(:mod:`~facetex.puppet.composite`, with :mod:`~facetex.puppet.lighting`,
:mod:`~facetex.puppet.mouth`, :mod:`~facetex.puppet.eyes`, :mod:`~facetex.puppet.detail` and
:mod:`~facetex.puppet.occluders`); :mod:`~facetex.puppet.puppetry` runs them over a video. The
persona itself (photo collection, expression-dependent textures) is :mod:`facetex.persona`."""

from .._lazy import lazy_attributes as _lazy_attributes

#: public name -> the module that defines it (imported on first use: the driver tracker's own
#: process imports only the driver module)
_LAZY = {
    "PuppetParams": "params",
    "MODES": "params",
    "TEXTURES": "params",
    "CORRESPONDENCES": "params",
    "PuppetSession": "puppetry",
    "load_puppet": "puppetry",
    "prepare_puppetry": "puppetry",
    "render_frames": "puppetry",
    "puppeteer": "puppetry",
    "Puppeteer": "puppeteer",
    "neutral_texture": "puppeteer",
    "neutral_textures": "puppeteer",
    "target_fiducials": "puppeteer",
    "DriverCollection": "correspondence",
    "driver_collection": "correspondence",
    "collection_correspondence": "correspondence",
    "landmark_correspondence": "correspondence",
    "puppet_average_shape": "correspondence",
    "DriverParams": "driver",
    "DriverTrack": "driver",
    "DriverMotion": "driver",
    "track_driver": "driver",
    "driver_motion": "driver",
    "DeformParams": "deform",
    "DeformationTransfer": "deform",
    "FACE_OVAL": "composite",
    "CompositeParams": "composite",
    "boundary_color_step": "composite",
    "composite_face": "composite",
    "fit_sh_lighting": "lighting",
    "linear_to_srgb": "lighting",
    "match_color_statistics": "lighting",
    "mouth_interior": "mouth",
    "eye_interior": "eyes",
    "poisson_blend": "composite",
    "relight": "lighting",
    "sh_basis": "lighting",
    "sh_shading": "lighting",
    "srgb_to_linear": "lighting",
}

__getattr__, __dir__ = _lazy_attributes(__name__, globals(), _LAZY)

__all__ = list(_LAZY)
