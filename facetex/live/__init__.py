"""Live puppetry (issue 26): a persona puppet driven by a stream of frames as they arrive — a
camera, a video played at its own frame rate, a URL, or frames handed in one at a time (the
studio). :class:`LiveSession` is the per-frame core (causal tracking and smoothing, the offline
puppet per frame); :func:`run_live` reads a source, drops stale frames, pipelines the stages over
two threads and writes to a window, a file or a callback."""

from .._lazy import lazy_attributes as _lazy_attributes

_LAZY = {
    "LiveSession": "session",
    "LiveParams": "params",
    "LiveStats": "stats",
    "OneEuroParams": "filters",
    "OneEuroFilter": "filters",
    "one_euro_step": "filters",
    "CausalTracker": "motion",
    "LiveMotion": "motion",
    "run_live": "runner",
    "open_source": "sources",
    "LatestFrame": "sources",
    "PushSource": "sources",
}

__getattr__, __dir__ = _lazy_attributes(__name__, globals(), _LAZY)

__all__ = list(_LAZY)
