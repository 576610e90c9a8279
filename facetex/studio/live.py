"""The Live page's WebSocket: camera frames in, puppet frames out.

``WS /api/live?persona=<id>&size=256&mode=composite``. The protocol, one frame in flight (the
page drops the camera frames it captures while waiting: the newest wins)::

    server -> {"status": "loading"}              the engine is being made (persona load, warm-up)
    server -> {"status": "ready", "engine": ...}
    page   -> <binary: a JPEG camera frame>
    server -> {"face": true, "server_ms": 41.2}  then <binary: the JPEG puppet frame>
           or {"face": false, "server_ms": 12.0} (no usable face: no frame follows)
    server -> {"error": "<one line>"}            then the socket is closed

The page measures fps and latency itself (send to receive, in its own clock). The engine comes
from :func:`facetex.studio.live_engine.make_live_engine`, the one place to swap in another; it runs
on a worker thread, so the server keeps serving. One Live session at a time: a second one is told
so (the machine's cores are the limit, and a second session would halve both).
"""

# no `from __future__ import annotations`: FastAPI reads the routes' annotations, whose types are imported
# inside the factory (fastapi is optional), so they must be evaluated where they are written

import threading
import time

from ..errors import BadInputError, FacetexError

#: largest camera frame accepted (a 1080p JPEG is ~0.3-0.5 MB)
MAX_FRAME_BYTES = 4 * 2**20
JPEG_QUALITY = 85


def _decode(data: bytes):
    import cv2
    import numpy as np

    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        raise BadInputError("a camera frame is not a JPEG or PNG image")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _encode(frame) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 RGB image
        raise BadInputError("the puppet frame could not be encoded")
    return buf.tobytes()


def add_routes(app, config, jobs) -> None:
    from fastapi import WebSocket, WebSocketDisconnect
    from starlette.concurrency import run_in_threadpool

    from .live_engine import make_live_engine
    from .submit import personas

    busy = threading.Lock()

    @app.websocket("/api/live")
    async def live(ws: WebSocket, persona: str = "", size: int = 256, mode: str = "composite"):
        await ws.accept()
        if not busy.acquire(blocking=False):
            await ws.send_json({"error": "another Live session is running on this studio: try again when it ends"})
            await ws.close()
            return
        engine = None
        try:
            chosen = personas(config, jobs).get(persona)  # an id of the table, never a path
            if chosen is None:
                raise BadInputError(f"no persona {persona[:40]!r}: build or upload one first")
            await ws.send_json({"status": "loading", "persona": chosen[0]})
            engine = await run_in_threadpool(make_live_engine, chosen[1], size, mode)
            await ws.send_json({"status": "ready", "engine": type(engine).__name__, "size": size, "mode": mode})
            while True:
                msg = await ws.receive()
                if msg["type"] == "websocket.disconnect":
                    break
                data = msg.get("bytes")
                if data is None:
                    raise BadInputError("send camera frames as binary JPEG messages, not text")
                if len(data) > MAX_FRAME_BYTES:
                    raise BadInputError(f"a camera frame of {len(data) / 2**20:.1f} MB: the limit is "
                                        f"{MAX_FRAME_BYTES / 2**20:.0f} MB")
                t0 = time.perf_counter()
                frame = await run_in_threadpool(_decode, data)
                out = await run_in_threadpool(engine.process, frame)
                jpeg = None if out is None else await run_in_threadpool(_encode, out)
                await ws.send_json({"face": jpeg is not None, "server_ms": round(1000 * (time.perf_counter() - t0), 1)})
                if jpeg is not None:
                    await ws.send_bytes(jpeg)
        except WebSocketDisconnect:
            pass
        except FacetexError as e:
            await _close_with(ws, str(e).replace(str(config.workdir), "studio"))
        except Exception as e:  # noqa: BLE001 - the page shows one line, like the CLI's last resort
            await _close_with(ws, f"internal error: {type(e).__name__}: {e}")
        finally:
            if engine is not None and callable(getattr(engine, "close", None)):  # close() is optional
                await run_in_threadpool(engine.close)
            busy.release()


async def _close_with(ws, message: str) -> None:
    """Send ``{"error": message}`` and close; the page may have gone already."""
    try:
        await ws.send_json({"error": message})
        await ws.close()
    except Exception:  # noqa: BLE001 - nobody left to tell
        pass
