"""Fixtures of the live tests: a tiny persona and short driver videos from the bundled samples."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="session")
def live_persona(tmp_path_factory):
    """A .persona of 8 jittered copies of frl_004 neutral/smiling (half-size canonical frame)."""
    from _photos import build_tiny_persona

    return build_tiny_persona(tmp_path_factory.mktemp("live_persona") / "tiny.persona", seed=0)


def driver_frames(n_morph: int = 8, n_blank: int = 2, n_hold: int = 3, side: int = 192) -> list[np.ndarray]:
    """uint8 frames: frl_004 neutral -> smiling (cross-fade of the aligned pair), ``n_blank`` grey
    frames (face lost), ``n_hold`` smiling frames."""
    import cv2

    from facetex._resources import sample_path
    from facetex.io import read_image, to_uint8

    a = cv2.resize(read_image(sample_path("frl_004_neutral.jpg")), (side, side), interpolation=cv2.INTER_AREA)
    b = cv2.resize(read_image(sample_path("frl_004_smiling.jpg")), (side, side), interpolation=cv2.INTER_AREA)
    frames = [to_uint8((1 - t) * a + t * b) for t in np.linspace(0, 1, n_morph)]
    frames += [np.full((side, side, 3), 115, np.uint8)] * n_blank + [to_uint8(b)] * n_hold
    return frames


@pytest.fixture(scope="session")
def live_videos(tmp_path_factory):
    """name -> path: face.mp4 (a face, 25 fps), noface.mp4 (grey frames), text.mp4 (not a video)."""
    from facetex.io import write_video

    d = tmp_path_factory.mktemp("live_videos")
    frames = driver_frames(n_blank=0)
    write_video(d / "face.mp4", frames + frames[::-1], 25)
    write_video(d / "noface.mp4", [np.full((120, 160, 3), 100 + 3 * i, np.uint8) for i in range(12)], 25)
    (d / "text.mp4").write_text("not a video\n")
    return {p.name: p for p in d.iterdir()}
