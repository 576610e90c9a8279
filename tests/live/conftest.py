"""Fixtures of the live tests: a tiny persona and short driver videos from the bundled samples."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="session")
def live_persona(tmp_path_factory):
    """A .persona of 8 jittered copies of frl_004 neutral/smiling (half-size canonical frame)."""
    from _photos import build_tiny_persona

    return build_tiny_persona(tmp_path_factory.mktemp("live_persona") / "tiny.persona", seed=0)


@pytest.fixture(scope="session")
def live_videos(tmp_path_factory):
    """name -> path: face.mp4 (a face, 25 fps), noface.mp4 (grey frames), text.mp4 (not a video)."""
    from _live import driver_frames
    from facetex.io import write_video

    d = tmp_path_factory.mktemp("live_videos")
    frames = driver_frames(n_blank=0)
    write_video(d / "face.mp4", frames + frames[::-1], 25)
    write_video(d / "noface.mp4", [np.full((120, 160, 3), 100 + 3 * i, np.uint8) for i in range(12)], 25)
    (d / "text.mp4").write_text("not a video\n")
    return {p.name: p for p in d.iterdir()}
