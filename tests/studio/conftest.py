"""Fixtures of the studio tests: a real uvicorn server on a free localhost port (started by the
tests, in a thread), a tiny persona, a driver clip and a camera clip (.y4m) made from the bundled
samples. Skipped with the reason when the studio extra is not installed."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from _studio import Server, face_frames, write_y4m
from facetex.io import write_video

pytest.importorskip("fastapi", reason="the studio extra is not installed (pip install -e '.[studio]')")
pytest.importorskip("uvicorn", reason="the studio extra is not installed (pip install -e '.[studio]')")


@pytest.fixture(scope="session")
def photo_dir(tmp_path_factory) -> Path:
    """8 jittered copies of the bundled frl_004 neutral and smiling portraits."""
    from _photos import write_jittered_copies

    folder = tmp_path_factory.mktemp("studio_photos")
    write_jittered_copies(folder, 4, np.random.default_rng(0))
    return folder


@pytest.fixture(scope="session")
def personas_dir(photo_dir, tmp_path_factory) -> Path:
    """A folder with one tiny persona (half-size canonical frame: fast to load and render)."""
    from _photos import build_tiny_persona

    folder = tmp_path_factory.mktemp("studio_personas")
    build_tiny_persona(folder / "tiny.persona", photos=photo_dir)
    return folder


@pytest.fixture(scope="session")
def driver_clip(tmp_path_factory) -> Path:
    return write_video(tmp_path_factory.mktemp("studio_driver") / "driver.mp4", face_frames(12), fps=10)


@pytest.fixture(scope="session")
def camera_clip(tmp_path_factory) -> Path:
    """The fake camera's clip: 320x240 (the size the Live page asks for), a face drifting."""
    frames = [cv2.copyMakeBorder(f, 0, 0, 40, 40, cv2.BORDER_REPLICATE) for f in face_frames(25)]
    return write_y4m(tmp_path_factory.mktemp("studio_camera") / "camera.y4m", frames + frames[::-1])


@pytest.fixture(scope="session")
def studio(tmp_path_factory, personas_dir):
    """The studio on a free localhost port (a real uvicorn server), with the tiny persona offered."""
    from facetex.studio import create_app

    app = create_app(tmp_path_factory.mktemp("studio_work"), personas_dir=personas_dir)
    with Server(app) as server:
        server.app = app
        yield server
