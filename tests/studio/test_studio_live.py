"""The Live page's WebSocket protocol with the streaming engine (facetex.live) and the tiny persona:
camera frames sent with ids, without waiting (at most the server's max_in_flight unanswered),
replies in order, each one binary message (a 12-byte header with the id, kind and server time, then
the JPEG) (warm-up first, then puppet frames of the asked size), one-line errors, one session at a
time, and no child process left behind."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from _studio import face_frames

pytest.importorskip("fastapi", reason="the studio extra is not installed (pip install -e '.[studio]')")


def _message(fid: int, frame: np.ndarray) -> bytes:
    return fid.to_bytes(4, "big") + cv2.imencode(".jpg", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))[1].tobytes()


def _reply(data: bytes):
    """(header dict, decoded image or None) of a reply message."""
    from facetex.studio.live import KINDS, REPLY_HEADER

    fid, kind, a, b, server_ms = REPLY_HEADER.unpack_from(data)
    assert a == b == 0
    body = data[REPLY_HEADER.size:]
    img = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_COLOR) if body else None
    return {"id": fid, "kind": {v: k for k, v in KINDS.items()}[kind], "frame": bool(body), "server_ms": server_ms}, img


def _children() -> set:
    """This process's live child processes (from /proc: their parent's pid, not zombies)."""
    import os
    from pathlib import Path

    pids = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # gone meanwhile
            continue
        if int(fields[1]) == os.getpid() and fields[0] != "Z":
            pids.add(int(stat.parent.name))
    return pids


def _stream(ws, frames, max_in_flight: int, until_puppets: int = 3, limit: int = 120) -> list:
    """Send frames (cycling) with ids 0, 1, ... keeping at most ``max_in_flight`` unanswered, until
    ``until_puppets`` puppet frames came back; the replies as (json, decoded image or None)."""
    sent, replies, unanswered, puppets = [], [], 0, 0
    while puppets < until_puppets:
        while unanswered < max_in_flight and len(sent) < limit:
            ws.send_bytes(_message(len(sent), frames[len(sent) % len(frames)]))
            sent.append(len(sent))
            unanswered += 1
        assert unanswered, f"no puppet frame after {limit} frames: {replies[-3:]}"
        msg = ws.receive()
        assert msg.get("text") is None, msg["text"]
        meta, img = _reply(msg["bytes"])
        replies.append((meta, img))
        # the replies come in order: this one answers its id and drops the older unanswered ones
        unanswered = sum(1 for i in sent if i > meta["id"])
        puppets += meta["kind"] == "puppet"
    return sent, replies


def test_websocket_streams_puppet_frames_with_ids_and_one_line_errors(tmp_path, personas_dir):
    from fastapi.testclient import TestClient

    from facetex.studio import create_app

    before = _children()
    app = create_app(tmp_path / "work", personas_dir=personas_dir)
    frames = [cv2.copyMakeBorder(f, 0, 0, 40, 40, cv2.BORDER_REPLICATE) for f in face_frames(12)]  # 320 x 240
    frames += frames[::-1]
    with TestClient(app) as c:
        persona = c.get("/api/personas").json()[0]["id"]
        with c.websocket_connect(f"/api/live?persona={persona}&size=160&mode=composite") as ws:
            assert ws.receive_json()["status"] == "loading"
            ready = ws.receive_json()
            assert ready["status"] == "ready" and ready["size"] == 160 and ready["engine"] == "facetex.live"
            assert ready["max_in_flight"] == 4 and ready["frame_side"] == 256  # at least the tracker's 256 px
            # a second session while this one runs is refused with one line
            with c.websocket_connect(f"/api/live?persona={persona}") as ws2:
                assert "another Live session" in ws2.receive_json()["error"]
            sent, replies = _stream(ws, frames, ready["max_in_flight"])
            ids = [m["id"] for m, _ in replies]
            assert set(ids) <= set(sent) and ids == sorted(set(ids))  # each reply names a sent frame, in order
            kinds = [m["kind"] for m, _ in replies]
            assert set(kinds) <= {"warmup", "puppet", "lost"} and kinds[0] == "warmup"  # the reference first
            assert kinds.index("puppet") >= 7  # ~8 tracked frames make the reference
            for meta, img in replies:
                assert meta["frame"] == (meta["kind"] != "warmup") and meta["server_ms"] > 0
                if meta["kind"] == "puppet":
                    assert img.shape == (120, 160, 3)  # the camera's aspect, longer side 160
            ws.send_bytes(b"\0\0\0\x07not a jpeg")
            while True:  # the replies of frames still in flight, then the error
                msg = ws.receive()
                if msg.get("text") is not None:
                    break
            assert json.loads(msg["text"]) == {"error": "a camera frame is not a JPEG or PNG image"}
        # the first session has ended, so a second one starts; a text message is refused
        with c.websocket_connect(f"/api/live?persona={persona}&mode=face&size=128") as ws:
            assert ws.receive_json()["status"] == "loading"
            ws.send_text("hello")
            ready = ws.receive_json()
            assert ready["status"] == "ready" and ready["frame_side"] == 256
            assert "binary messages" in ws.receive_json()["error"]
        with c.websocket_connect(f"/api/live?persona={persona}&size=400") as ws:
            assert ws.receive_json()["status"] == "loading"
            assert ws.receive_json()["frame_side"] == 400  # a larger output asks for larger frames
        with c.websocket_connect(f"/api/live?persona={persona}&size=5000") as ws:
            assert ws.receive_json()["status"] == "loading"
            assert ws.receive_json() == {"error": "live size must be 32..1024 px, got 5000"}
        with c.websocket_connect("/api/live?persona=../../etc/passwd") as ws:
            assert "no persona" in ws.receive_json()["error"]
    app.state.jobs.close()
    # the sessions stopped their tracking and rendering processes
    assert _children() - before == set()


def test_a_session_cut_short_still_frees_the_studio(tmp_path, personas_dir, monkeypatch):
    """The test client cancels the handler as soon as it closes the socket (so can a stopping
    server): the session's clean-up and the one-session lock must survive that cancellation, or the
    next page is told another session is running (seen once in a full test run)."""
    import importlib
    import time as _time

    from fastapi.testclient import TestClient

    from facetex.studio import create_app

    live = importlib.import_module("facetex.studio.live")

    def slow_open(*args, **kwargs):  # still opening when the page goes away (cancelled meanwhile)
        _time.sleep(0.5)

    app = create_app(tmp_path / "work", personas_dir=personas_dir)
    with TestClient(app) as c:
        persona = c.get("/api/personas").json()[0]["id"]
        monkeypatch.setattr(live, "open_session", slow_open)
        with c.websocket_connect(f"/api/live?persona={persona}") as ws:
            assert ws.receive_json()["status"] == "loading"
        monkeypatch.undo()
        with c.websocket_connect(f"/api/live?persona={persona}&size=5000") as ws:
            assert ws.receive_json()["status"] == "loading"
            assert ws.receive_json() == {"error": "live size must be 32..1024 px, got 5000"}
    app.state.jobs.close()
