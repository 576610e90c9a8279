"""The Live page's engine interface (the contract any engine behind ``make_live_engine`` keeps) and
the WebSocket protocol, with the tiny persona: a face frame gives a puppet frame of the asked size,
a frame without a face gives None, never the input back."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from _studio import face_frames

pytest.importorskip("fastapi", reason="the studio extra is not installed (pip install -e '.[studio]')")


@pytest.fixture(scope="module")
def engine(personas_dir):
    from facetex.studio.live_engine import make_live_engine

    e = make_live_engine(personas_dir / "tiny.persona", size=200, mode="face")
    yield e
    e.close()


def test_engine_turns_a_face_frame_into_a_puppet_frame(engine):
    frame = cv2.copyMakeBorder(face_frames(1)[0], 0, 0, 40, 40, cv2.BORDER_REPLICATE)  # 320 x 240
    out = engine.process(frame)
    assert out is not None and out.dtype == np.uint8 and out.ndim == 3 and out.shape[2] == 3
    assert max(out.shape[:2]) == 200 and out.shape[:2] == (150, 200)  # the camera's aspect, longer side 200
    # face mode: the puppet's face alone on plain grey, where the camera frame had its background
    plain = np.all(np.abs(out.astype(int) - 128) <= 2, axis=2)
    assert plain[:, :30].all() and plain[:, -30:].all() and 0.5 < plain.mean() < 0.95
    face = out[~plain].astype(np.float32)
    assert face[:, 0].mean() > face[:, 2].mean() + 10  # skin: redder than blue


def test_engine_returns_none_without_a_face_and_checks_its_arguments(engine, personas_dir):
    from facetex.errors import BadInputError
    from facetex.studio.live_engine import make_live_engine

    assert engine.process(np.full((240, 320, 3), 120, np.uint8)) is None
    with pytest.raises(BadInputError, match="mode"):
        make_live_engine(personas_dir / "tiny.persona", size=200, mode="cartoon")
    with pytest.raises(BadInputError, match="size"):
        make_live_engine(personas_dir / "tiny.persona", size=5000, mode="face")


def test_websocket_sends_puppet_frames_and_one_line_errors(tmp_path, personas_dir):
    from fastapi.testclient import TestClient

    from facetex.studio import create_app

    app = create_app(tmp_path / "work", personas_dir=personas_dir)
    frame = cv2.copyMakeBorder(face_frames(1)[0], 0, 0, 40, 40, cv2.BORDER_REPLICATE)
    jpeg = cv2.imencode(".jpg", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))[1].tobytes()
    with TestClient(app) as c:
        persona = c.get("/api/personas").json()[0]["id"]
        with c.websocket_connect(f"/api/live?persona={persona}&size=160&mode=composite") as ws:
            assert ws.receive_json()["status"] == "loading"
            ready = ws.receive_json()
            assert ready["status"] == "ready" and ready["size"] == 160
            for _ in range(2):
                ws.send_bytes(jpeg)
                meta = ws.receive_json()
                assert meta["face"] is True and meta["server_ms"] > 0
                img = cv2.imdecode(np.frombuffer(ws.receive_bytes(), np.uint8), cv2.IMREAD_COLOR)
                assert img.shape == (120, 160, 3)
            ws.send_bytes(b"not a jpeg")
            assert ws.receive_json() == {"error": "a camera frame is not a JPEG or PNG image"}
        # one session at a time: the first has ended, so a second one starts
        with c.websocket_connect(f"/api/live?persona={persona}") as ws:
            assert ws.receive_json()["status"] == "loading"
            ws.send_text("hello")
            assert ws.receive_json()["status"] == "ready"
            assert "binary JPEG" in ws.receive_json()["error"]
    app.state.jobs.close()
