"""Helpers of the studio tests (tests/studio): frames of a bundled face, a .y4m camera clip
for Chromium's fake camera, and a real uvicorn server on a free localhost port in a thread."""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from facetex._resources import sample_path
from facetex.io import read_image


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


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """uvicorn serving ``app`` on 127.0.0.1 in a thread; ``url`` once it listens."""

    def __init__(self, app):
        import uvicorn

        self.port = free_port()
        self.server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="warning",
                                                    ws_per_message_deflate=False))  # as `facetex serve`
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
