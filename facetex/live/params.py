"""Settings of the live puppetry (:class:`LiveParams`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import BadInputError
from .filters import OneEuroParams

__all__ = ["LiveParams"]


@dataclass(frozen=True)
class LiveParams:
    """Settings of :class:`facetex.live.LiveSession` beyond the puppet's own (:class:`facetex.puppet.PuppetParams`).

    warmup / max_warmup: the driver's reference (its mean mesh, canonical frame and mean landmarks,
    which the offline puppetry takes from the whole clip) is made from the tracked frames seen before
    the puppet is ready: at least ``warmup`` frames, the last ``max_warmup`` of them while the persona
    is still loading. pose / shape / landmarks / lips: One-Euro filters (:mod:`facetex.live.filters`)
    of the head pose (rotation vector in rad, log scale and translation in px), the mesh's expression
    residuals (canonical px), the un-posed landmarks (canonical px) and the lip and jaw landmarks
    (None, the default: unfiltered, as the offline lips: a syllable's opening lasts 3-6 frames). track_side:
    frames are tracked with their longer side at most this (px; the output panel is made from the
    full frame). weight_smoothing: the texture's regional weights are averaged with the past frames'
    of the same expression (a one-sided bilateral filter, Gaussian of this many seconds; 0: each
    frame's own; :meth:`facetex.live.LiveSession._texture`). static_start: puppet frames start before
    the texture stacks are ready, with the persona's stored static texture (:mod:`facetex.live._loading`),
    and cross-fade to the expression textures over ``fade_frames`` frames once they are; False: the
    first puppet frame waits for the stacks. stack_cache: the persona's texture stacks are memory-mapped
    from facetex's cache folder, written there by the first session of a ``.persona`` file (~1 MB
    per photo; :mod:`facetex.persona._stack_cache`). reuse_texture: a frame that waited for the
    stages (it arrived while the previous one was still being prepared: the stream is at the machine's
    limit) takes the previous frame's texture blend (with its own mouth fill) instead of a new one,
    never two frames in a row: the blend is the costliest step of this process, and the filtered
    weights change little from one frame to the next. shape_floor / shape_factor: a tracked face whose landmarks differ
    from the reference's mean shape (similarity-aligned, mean point distance over the eye distance) by
    more than max(shape_floor, shape_factor x the reference frames' median) counts as lost (squashed or
    torn landmarks: the offline check of :func:`facetex.puppet.driver.implausible_shapes`, against the
    reference instead of the whole clip). lost_output: what a frame without a usable face shows, "driver" (its own frame,
    a plain panel in face mode, as the offline puppetry) or "last" (the last puppet frame). tracking:
    "process" (default; a child process tracks frame t+1 while this one renders frame t:
    :mod:`facetex.live._tracking`) or "thread" (in the calling thread). render: "process" (default;
    a child process renders and composites frame t while this one makes frame t+1's mesh and
    texture: :mod:`facetex.live._render`) or "thread"."""

    warmup: int = 8
    max_warmup: int = 50
    pose: OneEuroParams = field(default_factory=lambda: OneEuroParams(min_cutoff=2.0, beta=0.5, d_cutoff=1.0))
    shape: OneEuroParams = field(default_factory=lambda: OneEuroParams(min_cutoff=3.0, beta=0.5, d_cutoff=1.0))
    landmarks: OneEuroParams = field(default_factory=lambda: OneEuroParams(min_cutoff=3.0, beta=0.5,
                                                                             d_cutoff=1.0))
    lips: OneEuroParams | None = None
    track_side: int = 640
    weight_smoothing: float = 0.12
    static_start: bool = True
    fade_frames: int = 12
    stack_cache: bool = True
    reuse_texture: bool = True
    shape_floor: float = 0.08
    shape_factor: float = 4.0
    lost_output: str = "driver"
    tracking: str = "process"
    render: str = "process"

    def check(self) -> "LiveParams":
        """Self, or BadInputError naming the first bad value."""
        if not 1 <= self.warmup <= self.max_warmup:
            raise BadInputError(f"live warm-up must be 1 <= warmup <= max_warmup, got {self.warmup}, {self.max_warmup}")
        if self.track_side < 64:
            raise BadInputError(f"live track_side must be >= 64 px, got {self.track_side}")
        if not self.weight_smoothing >= 0:
            raise BadInputError(f"live weight_smoothing must be >= 0 seconds, got {self.weight_smoothing}")
        if self.lost_output not in ("driver", "last"):
            raise BadInputError(f"live lost_output must be 'driver' or 'last', got {self.lost_output!r}")
        for name in ("tracking", "render"):
            if getattr(self, name) not in ("process", "thread"):
                raise BadInputError(f"live {name} must be 'process' or 'thread', got {getattr(self, name)!r}")
        return self
