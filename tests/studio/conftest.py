"""Shared pieces of the studio tests: a real uvicorn server on a free localhost port (started by
the tests, in a thread), a tiny persona, a driver clip and a camera clip (.y4m) made from the
bundled samples. Skipped with the reason when the studio extra is not installed."""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from facetex._resources import sample_path
from facetex.io import read_image, write_video

pytest.importorskip("fastapi", reason="the studio extra is not installed (pip install -e '.[studio]')")
pytest.importorskip("uvicorn", reason="the studio extra is not installed (pip install -e '.[studio]')")


def face_frames(n: int = 12, side: int = 240) -> list[np.ndarray]:
    """``n`` frames of frl_004 cross-fading from neutral to smiling while drifting a few pixels:
    a face in every frame, a little motion (uint8)."""
    a, b = (cv2.resize(read_image(sample_path(f"frl_004_{e}.jpg")), (side, side), interpolation=cv2.INTER_AREA)
            for e in ("neutral", "smiling"))
    frames = []
    for k in range(n):
        t = k / max(1, n - 1)
        img = (1 - t) * a + t * b
        m = np.float32([[1, 0, 3 * np.sin(k / 2)], [0, 1, 2 * np.cos(k / 3)]])
        img = cv2.warpAffine(img, m, (side, side), borderMode=cv2.BORDER_REPLICATE)
        frames.append(np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8))
    return frames


def write_y4m(path: Path, frames: list[np.ndarray], fps: int = 25) -> Path:
    """A YUV4MPEG2 clip (Chromium's fake camera reads it): a text header, then per frame
    ``FRAME`` and the I420 planes (OpenCV's RGB -> YUV I420 gives them in order)."""
    h, w = frames[0].shape[:2]
    with open(path, "wb") as fh:
        fh.write(f"YUV4MPEG2 W{w} H{h} F{fps}:1 Ip A1:1 C420jpeg\n".encode())
        for f in frames:
            fh.write(b"FRAME\n")
            fh.write(cv2.cvtColor(f, cv2.COLOR_RGB2YUV_I420).tobytes())
    return path


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
    from facetex.persona import PersonaParams, build_persona

    folder = tmp_path_factory.mktemp("studio_personas")
    persona = build_persona(photo_dir, jobs=1, params=PersonaParams(min_photos=6, size=(96, 120)))
    persona.save(folder / "tiny.persona")
    return folder


@pytest.fixture(scope="session")
def driver_clip(tmp_path_factory) -> Path:
    return write_video(tmp_path_factory.mktemp("studio_driver") / "driver.mp4", face_frames(12), fps=10)


@pytest.fixture(scope="session")
def camera_clip(tmp_path_factory) -> Path:
    """The fake camera's clip: 320x240 (the size the Live page asks for), a face drifting."""
    frames = [cv2.copyMakeBorder(f, 0, 0, 40, 40, cv2.BORDER_REPLICATE) for f in face_frames(25)]
    return write_y4m(tmp_path_factory.mktemp("studio_camera") / "camera.y4m", frames + frames[::-1])


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """uvicorn serving ``app`` on 127.0.0.1 in a thread; ``url`` once it listens."""

    def __init__(self, app):
        import uvicorn

        self.port = free_port()
        self.server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="warning"))
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.url = f"http://127.0.0.1:{self.port}"

    def __enter__(self):
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError("the studio's server did not start")
            time.sleep(0.05)
        return self

    def __exit__(self, *exc):
        self.server.should_exit = True
        self.thread.join(30)


@pytest.fixture(scope="session")
def studio(tmp_path_factory, personas_dir):
    """The studio on a free localhost port (a real uvicorn server), with the tiny persona offered."""
    from facetex.studio import create_app

    app = create_app(tmp_path_factory.mktemp("studio_work"), personas_dir=personas_dir)
    with Server(app) as server:
        server.app = app
        yield server
