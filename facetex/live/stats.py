"""Counters and latency percentiles of a live stream (:meth:`facetex.live.LiveSession.stats`)."""

from __future__ import annotations

import threading
import time

import numpy as np

__all__ = ["LiveStats"]


class LiveStats:
    """Thread-safe counts of a stream's frames and the latencies of its outputs.

    Frames are counted as they come in (``frames_in``), are dropped before processing (stale:
    a newer frame arrived first), or come out (``frames_out``: puppet frames, frames without a
    usable face, warm-up frames without an output). Latency: from a frame's arrival to its output.
    """

    def __init__(self, start: float | None = None):
        self.start = time.perf_counter() if start is None else start
        self._lock = threading.Lock()
        self.frames_in = self.dropped = self.puppet = self.lost = self.warmup = 0
        self.arrivals: list[float] = []
        self.drops: list[float] = []
        self.latencies: list[float] = []
        self.out_times: list[float] = []
        self.first_puppet: float | None = None
        self.first_puppet_unix: float | None = None
        self.stage: dict[str, list[float]] = {}

    def arrived(self, n: int = 1, now: float | None = None) -> None:
        now = time.perf_counter() if now is None else now
        with self._lock:
            self.frames_in += n
            self.arrivals.extend([now] * n)

    def drop(self, n: int = 1, now: float | None = None) -> None:
        now = time.perf_counter() if now is None else now
        with self._lock:
            self.dropped += n
            self.drops.extend([now] * n)

    def stage_time(self, name: str, seconds: float) -> None:
        with self._lock:
            self.stage.setdefault(name, []).append(seconds)

    def output(self, arrival: float, kind: str, now: float | None = None) -> None:
        """One frame done (``kind``: "puppet", "lost" or "warmup", the last without an output)."""
        now = time.perf_counter() if now is None else now
        with self._lock:
            setattr(self, kind, getattr(self, kind) + 1)
            if kind == "warmup":
                return
            if kind == "puppet" and self.first_puppet is None:
                self.first_puppet, self.first_puppet_unix = now, time.time() - (time.perf_counter() - now)
            self.latencies.append(now - arrival)
            self.out_times.append(now)

    def summary(self, *, settle: float = 1.0) -> dict:
        """{"frames_in", "frames_out", "puppet_frames", "lost_frames", "warmup_frames", "dropped" and
        "dropped_pct" (of the frames that arrived from the first puppet frame on), "dropped_startup" (before it), "fps", "sustained_fps", "latency_ms_p50", "latency_ms_p95", "latency_ms_max",
        "first_puppet_s", "stage_ms"}: fps over all outputs from the first; sustained fps and the
        latencies over the outputs after the first ``settle`` seconds of puppet frames (the warm-up:
        imports, first calls); stage_ms: the median milliseconds of each timed stage."""
        with self._lock:
            lat, out = np.array(self.latencies), np.array(self.out_times)
            arr, drops = np.array(self.arrivals), np.array(self.drops)
            first = self.first_puppet
            d = dict(frames_in=self.frames_in, frames_out=len(out), puppet_frames=self.puppet, lost_frames=self.lost,
                     warmup_frames=self.warmup, dropped=self.dropped,
                     stage_ms={k: round(1000 * float(np.median(v)), 2) for k, v in self.stage.items()})
        # dropped frames from the first puppet frame on (before it: the persona loading and the
        # reference's warm-up, counted apart as dropped_startup)
        t1 = first if first is not None else np.inf
        n_in, n_drop = int((arr >= t1).sum()), int((drops >= t1).sum())
        d.update(dropped=n_drop, dropped_startup=int((drops < t1).sum()),
                 dropped_pct=round(100.0 * n_drop / max(n_in, 1), 2))
        d["fps"] = round(float((len(out) - 1) / (out[-1] - out[0])), 2) if len(out) > 1 and out[-1] > out[0] else 0.0
        keep = out >= (first + settle) if first is not None else np.zeros(len(out), bool)
        if keep.sum() < 10:  # a short stream: all of it
            keep = np.ones(len(out), bool)
        o = out[keep]
        d["sustained_fps"] = round(float((len(o) - 1) / (o[-1] - o[0])), 2) if len(o) > 1 and o[-1] > o[0] else 0.0
        lk = lat[keep] if len(lat) else lat
        for p in (50, 95):
            d[f"latency_ms_p{p}"] = round(1000 * float(np.percentile(lk, p)), 1) if len(lk) else None
        d["latency_ms_max"] = round(1000 * float(lk.max()), 1) if len(lk) else None
        d["first_puppet_s"] = None if first is None else round(first - self.start, 3)
        d["first_puppet_unix"] = self.first_puppet_unix
        return d
