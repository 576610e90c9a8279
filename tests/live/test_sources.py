"""Stale frames are dropped, the newest is processed: the mailbox and the runner with a slow stage."""

from __future__ import annotations

import time

import numpy as np

from facetex.live.sources import LatestFrame, source_kind
from facetex.live.stats import LiveStats


def test_mailbox_keeps_the_newest():
    box = LatestFrame()
    assert box.put(1) is False
    assert box.put(2) is True  # 1 was never taken: dropped
    assert box.put(3) is True
    assert box.get() == 3
    assert box.get(timeout=0.01) is None  # empty
    box.put(4)
    box.close()
    assert box.get() == 4 and box.get() is None  # closed: what is left, then None


def test_source_kinds():
    assert source_kind(0) == source_kind("1") == source_kind("/dev/video2") == "camera"
    assert source_kind("rtsp://host/stream") == source_kind("http://x/y.m3u8") == "url"
    assert source_kind("clip.mp4") == source_kind("file:///tmp/a.mp4") == "file"


class _SlowSession:
    """A stand-in LiveSession whose first stage takes 0.12 s a frame (3 frame times at 25 fps)."""

    def __init__(self):
        self.stats_ = LiveStats()
        self.seen: list[int] = []

    def wait_loaded(self, timeout=None):
        return True

    def prepare(self, frame, *, arrival, t, fps, index):
        time.sleep(0.12)
        assert round(frame[0, 0, 0] / 8) == index  # the source's frame number
        return {"id": int(frame[0, 0, 0]), "arrival": arrival}

    def finish(self, work):
        self.seen.append(work["id"])
        self.stats_.output(work["arrival"], "puppet")
        return {"index": work["id"], "output": None, "kind": "puppet"}

    def require_face(self, source=None):
        pass

    def stats(self):
        return self.stats_.summary()


def test_slow_stage_drops_stale_frames_and_takes_the_newest(tmp_path):
    from facetex.io import write_video
    from facetex.live.runner import run_live

    n = 25
    frames = [np.full((64, 64, 3), 8 * i, np.uint8) for i in range(n)]  # frame i has value 8 i
    path = tmp_path / "ids.mp4"
    write_video(path, frames, 25, crf=0)
    s = _SlowSession()
    report = run_live(path, session=s)  # played in real time: 40 ms a frame
    ids = [round(v / 8) for v in s.seen]
    assert report["frames_in"] == n
    assert report["dropped"] > n // 3  # most frames could not be processed in time
    assert len(ids) + report["dropped"] + report["dropped_startup"] == n
    assert ids == sorted(ids) and len(set(ids)) == len(ids)  # in order, never twice
    assert ids[-1] == n - 1  # the newest frame is processed at the end
    assert max(np.diff(ids)) >= 2  # frames in between were skipped, not queued


class _FastSession(_SlowSession):
    def prepare(self, frame, *, arrival, t, fps, index):
        return {"id": int(frame[0, 0, 0]), "arrival": arrival}


def test_push_source_feeds_the_runner():
    """The studio's hook: frames pushed by the caller come out through on_frame (none lost when the
    stages keep up)."""
    import threading

    from facetex.live import PushSource
    from facetex.live.runner import run_live

    feed = PushSource(fps=25)
    s = _FastSession()
    seen = []
    th = threading.Thread(target=lambda: seen.append(run_live(feed, session=s, on_frame=lambda r: None)))
    th.start()
    for i in range(10):
        feed.push(np.full((32, 32, 3), i, np.uint8))
        time.sleep(0.02)
    feed.close()
    th.join(10)
    assert not th.is_alive()
    assert s.seen == list(range(10)) and seen[0]["frames_in"] == 10 and seen[0]["source"] == "pushed frames"
