"""The live tracker in a child process (:class:`ProcessTracker`, on :class:`~facetex.live._workers.ChildWorker`):
it tracks frame t+1 while this process renders frame t. dlib's landmark fit holds the GIL, so on a
thread it would stall the rest of the frame's work."""

from __future__ import annotations

__all__ = ["ProcessTracker"]


class _Tracker:
    """The child's object: its models loaded at once, a CausalTracker once the parameters come."""

    def __init__(self):
        from .motion import CausalTracker, load_tracking_models

        self.tracker = CausalTracker()
        load_tracking_models()

    def configure(self, params) -> None:
        from .motion import CausalTracker

        self.tracker = CausalTracker(params)

    def track(self, frame):
        return self.tracker(frame) + (self.tracker.detections,)

    def lose(self):
        self.tracker.lose()


def _make_tracker() -> _Tracker:
    return _Tracker()


class ProcessTracker:
    """:class:`facetex.live.motion.CausalTracker` in a child process: the same calls and results.
    Falls back to tracking in this process when no child can be started."""

    def __init__(self, params):
        from ._workers import worker
        from .motion import CausalTracker

        self.params = params
        self.detections = 0  # the child's count, updated with each frame
        self._local = None
        try:
            self._child = worker("facetex.live._tracking:_make_tracker", name="live tracking")
        except OSError:  # no usable interpreter for a child (embedded Python): track here
            self._child = None
            self._local = CausalTracker(params)
        else:
            self._child.cast("configure", params)

    def wait_ready(self) -> None:
        """Wait until the child has loaded its models."""
        if self._child is not None:
            self._child.wait_ready()

    def __call__(self, frame) -> tuple:
        if self._local is not None:
            r = self._local(frame)
            self.detections = self._local.detections
            return r
        *r, self.detections = self._child.call("track", frame)
        return tuple(r)

    def lose(self) -> None:
        if self._local is not None:
            self._local.lose()
        else:
            self._child.cast("lose")

    def close(self) -> None:
        if self._child is not None:
            self._child.close()
