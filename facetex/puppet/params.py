"""Settings of the puppetry (:class:`PuppetParams`) and its choices."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import BadInputError
from .composite import CompositeParams
from .deform import DeformParams
from .driver import DriverParams

__all__ = ["PuppetParams", "MODES", "TEXTURES", "CORRESPONDENCES"]

MODES = ("composite", "face")
TEXTURES = ("ours", "static")
CORRESPONDENCES = ("landmarks", "flow")


@dataclass(frozen=True)
class PuppetParams:
    """Driver-puppet correspondence: "landmarks" (ours, the default: a thin-plate spline between
    the two mean landmark sets) or "flow" (the paper's collection flow, Tom Hanks §6, with alpha,
    ratio, minWidth, outer, inner, SOR iterations; :mod:`facetex.puppet.puppetry` doc, 2);
    texture "ours" (expression-dependent) or "static" (the average texture); weights of the
    expression-dependent texture: "regional" (ours, ``neighbours`` K of the per-region
    adaptive sigma) or "global" (the paper's Eq. 2/3 with ``sigma`` and alpha 1), see
    :meth:`texture_params`; weight_smoothing: the regional weights are made temporally coherent by a
    bilateral filter over frames (Gaussian of this many seconds) and expression distance
    (``weight_range`` x each frame's adaptive sigma), 0 = per frame
    (:func:`facetex.persona.weights.temporal_weights`; :mod:`facetex.puppet.puppetry` doc, 4);
    plain: background colour of ``mode="face"``; composite: how the puppet is put into the
    driver's frame; supersample / supersample_composite: rasterization samples per pixel and
    axis in face / composite mode (anti-aliased silhouette; in composite mode the feathered
    driver outline is the edge, and the texture is low-passed to the pixel spacing either way);
    mouth_rest: the puppet's mean lip gap set to the driver's (:mod:`facetex.puppet.puppetry` doc); smile_rest:
    the puppet's mean mouth is the persona's at the driver's mean mouth-corner lift where that is lower
    than the persona's mean, within the lifts its photos show (:meth:`Puppeteer._smile_rest_motion`: a collection that mostly smiles smiled on a
    neutral driver); lip_sync: the
    puppet's lip and jaw landmarks follow the driver's (:meth:`Puppeteer.grid`); eye_rest: eyes
    narrower than the driver's are opened to the driver's mean lid gap (scaled), lid_sync: the
    puppet's eyelids follow the driver's (blinks; :meth:`Puppeteer.grid`); close_mouth: the
    texture's mouth interior is filled from its lips (:func:`facetex.puppet.mouth.fill_mouth_interior`):
    all of it when the driver's interior is drawn (``composite.mouth``: the persona's teeth at its
    texture's inner lips showed as a white rim round the driver's interior), else as the driver's
    lips close (no teeth sliver between closed lips);
    max_depth_error: a reconstructed average depth whose RMS
    difference to the generic face exceeds this fraction of the frame width is replaced by
    the generic depth (too few or too uniformly lit photos); shape "generic" skips the
    photometric-stereo reconstruction of the puppet and uses the generic face's depth;
    shape_photos: at most this many (evenly spaced) photos feed the photometric stereo (its SVD
    grows with the square of the count; a few dozen lightings determine the rank-4 factorization)."""

    flow_alpha: float = 0.02
    flow_ratio: float = 0.85
    flow_min_width: int = 20
    flow_outer: int = 4
    flow_inner: int = 1
    flow_sor: int = 40
    correspondence: str = "landmarks"
    sigma: float = 10.0
    texture: str = "ours"
    weights: str = "regional"
    neighbours: int = 3
    weight_smoothing: float = 0.12
    weight_range: float = 1.0
    plain: tuple[float, float, float] = (0.5, 0.5, 0.5)
    composite: CompositeParams = field(default_factory=CompositeParams)
    supersample: int = 2
    supersample_composite: int = 1
    mouth_rest: bool = True
    smile_rest: bool = True
    lip_sync: bool = True
    brow_rest: bool = True
    brow_sync: bool = True
    eye_rest: bool = True
    lid_sync: bool = True
    close_mouth: bool = True
    max_depth_error: float = 0.08
    shape: str = "collection"
    shape_photos: int = 128
    deform: DeformParams = field(default_factory=DeformParams)
    driver: DriverParams = field(default_factory=DriverParams)

    @property
    def needs_average_face(self) -> bool:
        """Whether the puppet needs the persona's average face (Fig. 6 d): the flow
        correspondence projects it, the static texture is it."""
        return self.texture == "static" or self.correspondence == "flow"

    def texture_params(self):
        """The :class:`facetex.persona.TextureParams` of the puppet's textures: the persona
        texture's defaults with the regional weights and the mouth's detail restored too
        (:data:`facetex.persona.params.RENDER_RESTORE`), :meth:`TextureParams.paper` with the
        global ones (both the static average and the blends use them, so one precomputation
        serves all)."""
        from ..persona.params import RENDER_RESTORE, WEIGHTS, TextureParams

        if self.weights not in WEIGHTS:
            raise BadInputError(f"unknown puppet texture weights {self.weights!r}: use one of {', '.join(WEIGHTS)}")
        if not self.weight_smoothing >= 0:
            raise BadInputError(f"weight smoothing must be >= 0 seconds, got {self.weight_smoothing}")
        if self.weights == "global":
            return TextureParams.paper(sigma=self.sigma)
        # the mouth's detail restored as well (RENDER_RESTORE): the persona texture's default leaves
        # it out (closer to a held-out photo in SSIM), the puppet's lips need it to read as lips
        return TextureParams(neighbours=self.neighbours, restore=RENDER_RESTORE)


