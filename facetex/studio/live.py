"""The Live page's WebSocket: camera frames in, puppet frames out, through the streaming engine.

``WS /api/live?persona=<id>&size=256&mode=composite``. The protocol::

    server -> {"status": "loading", "persona": name}   the session is being opened
    server -> {"status": "ready", "engine": "facetex.live", "size": 256, "mode": "composite",
               "max_in_flight": 4, "frame_side": 256}
    page   -> <binary: a 4-byte big-endian frame id, then a JPEG camera frame>   (at the camera's rate,
              scaled down so that its longer side is at most frame_side)
    server -> <binary: a 12-byte header (big-endian uint32 id, uint8 kind, uint8 0, uint16 0, float32
              server_ms), then the JPEG of the reply, or nothing>
              kind 1 "puppet": the puppet frame; 2 "lost": the face was lost, the JPEG is the camera's own
              frame (composite mode; a plain panel in face mode); 0 "warmup": no JPEG (the persona is
              loading, or the first ~8 tracked frames are making the driver's reference)
    server -> {"error": "<one line>"}                   then the socket is closed

Frames and replies are single binary messages (no base64, no JSON per frame), and a camera frame is
sent no larger than the output needs (``frame_side``: the output's longer side, at least
:data:`MIN_FRAME_SIDE` for the tracker): the page's JPEG encode, the server's decode and the bytes on
the socket are those of a 256 px frame, not of the camera's. ``facetex serve`` turns off the
WebSocket's per-message deflate, which only spent CPU on JPEGs on both sides.

The page sends frames without waiting for replies, at most ``max_in_flight`` unanswered at once (a
slow network then costs frames, not a growing queue). The server replies in frame order; a camera
frame the engine dropped as stale (a newer one came before it was taken: the newest wins) gets no
reply, so the page counts as dropped the ids older than a reply that never had one. ``server_ms`` is
the time from the frame's arrival at the server to its reply (decode, engine, JPEG); the page
measures the latency in its own clock (send to receive of the same id), its puppet fps and p50/p95.

The engine is a :class:`facetex.live.LiveSession` run by :func:`facetex.live.run_live` from a
:class:`facetex.live.PushSource` on a thread of its own (tracking and rendering in child processes,
docs/live.md); its ``on_frame`` hands each record to the event loop with ``call_soon_threadsafe``
and the JPEG encoding runs on the thread pool, so the loop only moves bytes. One Live session at a
time: a second one is told so (the machine's cores are the limit, and a second session would halve
both). When the socket closes, the source is closed, the runner ends and the session stops its
child processes.
"""

# no `from __future__ import annotations`: FastAPI reads the routes' annotations, whose types are imported
# inside the factory (fastapi is optional), so they must be evaluated where they are written

import asyncio
import struct
import threading
import time

from ..errors import BadInputError, FacetexError, NoFaceError

#: largest camera frame accepted (a 1080p JPEG is ~0.3-0.5 MB)
MAX_FRAME_BYTES = 4 * 2**20
JPEG_QUALITY = 85
#: camera frames the page may have sent without a reply (told to it in the "ready" message). The round
#: trip is ~100-150 ms in Chromium at 25 fps, so 3 held back 14 % of the camera's frames (20.4 fps with the
#: 519-photo persona) where 4 held back ~1 % (22.5-23 fps, the engine dropping the rest), same latency
MAX_IN_FLIGHT = 4
#: the Live page's output sizes (px, longer side): larger frames would not keep up with a camera
SIZES = (32, 1024)
MODES = ("composite", "face")
#: smallest longer side of the camera frames asked for (the tracker's landmarks need a face of ~80 px)
MIN_FRAME_SIDE = 256
#: a reply's header: frame id, kind, two zero fields, server ms
REPLY_HEADER = struct.Struct(">IBBHf")
KINDS = {"warmup": 0, "puppet": 1, "lost": 2}
_END = object()


def frame_side(size: int) -> int:
    """The longer side (px) the page scales its camera frames to: the output's, at least MIN_FRAME_SIDE."""
    return max(int(size), MIN_FRAME_SIDE)


def reply_message(fid, kind: str, server_ms, jpeg: bytes | None) -> bytes:
    """One reply: :data:`REPLY_HEADER` then the JPEG (nothing for a warm-up frame)."""
    head = REPLY_HEADER.pack(0xFFFFFFFF if fid is None else int(fid) & 0xFFFFFFFF, KINDS.get(kind, 0), 0, 0,
                             float(server_ms or 0.0))
    return head + (jpeg or b"")


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


def _frame_message(data) -> tuple:
    """(id, JPEG bytes) of a page's binary message; BadInputError for anything else."""
    if data is None:
        raise BadInputError("send camera frames as binary messages (a 4-byte id, then the JPEG), not text")
    if len(data) > MAX_FRAME_BYTES:
        raise BadInputError(f"a camera frame of {len(data) / 2**20:.1f} MB: the limit is "
                            f"{MAX_FRAME_BYTES / 2**20:.0f} MB")
    if len(data) < 5:
        raise BadInputError("a camera frame message is a 4-byte id followed by the JPEG")
    return int.from_bytes(data[:4], "big"), data[4:]


def open_session(persona_path, size: int, mode: str):
    """The :class:`facetex.live.LiveSession` of one Live page (the persona loads in the background:
    the frames that arrive meanwhile are tracked for the driver's reference).

    Parameters
    ----------
    persona_path : str or os.PathLike
        The puppet's ``.persona`` file.
    size : int
        Longer side of the puppet frames in px (32..1024).
    mode : {"composite", "face"}
        The puppet put into the camera frame, or the puppet face alone on grey.

    Returns
    -------
    facetex.live.LiveSession

    Raises
    ------
    ValueError
        (:class:`facetex.BadInputError`) a bad size or mode; (:class:`facetex.BadPersonaError`) not a persona.
    """
    from ..live import LiveSession

    if mode not in MODES:
        raise BadInputError(f"unknown live mode {mode!r}: use one of {', '.join(MODES)}")
    if not SIZES[0] <= int(size) <= SIZES[1]:
        raise BadInputError(f"live size must be {SIZES[0]}..{SIZES[1]} px, got {size}")
    return LiveSession(persona_path, size=int(size), mode=mode)


def _run(session, feed, post) -> None:
    """The runner's thread: ``post(record)`` per output record, ``post(error)`` on failure, then ``post(_END)``."""
    from ..live import run_live

    try:
        run_live(feed, session=session, wait=False,
                 on_frame=lambda rec: post({k: rec.get(k) for k in ("index", "kind", "output")}))
    except NoFaceError:  # the page left before a puppet frame came out: nothing to tell
        pass
    except BaseException as e:  # noqa: BLE001 - shown to the page as one line
        post(e)
    finally:
        post(_END)


def add_routes(app, config, jobs) -> None:
    import anyio
    from fastapi import WebSocket, WebSocketDisconnect
    from starlette.concurrency import run_in_threadpool

    from ..live import PushSource
    from .submit import personas

    busy = threading.Lock()

    @app.websocket("/api/live")
    async def live(ws: WebSocket, persona: str = "", size: int = 256, mode: str = "composite"):
        await ws.accept()
        if not busy.acquire(blocking=False):
            await ws.send_json({"error": "another Live session is running on this studio: try again when it ends"})
            await ws.close()
            return
        session = feed = runner = pinned = None
        tasks: list = []
        try:
            chosen = personas(config, jobs).get(persona)  # an id of the table, never a path
            if chosen is None:
                raise BadInputError(f"no persona {persona[:40]!r}: build or upload one first")
            if persona.startswith("job-"):  # a persona built or uploaded here: kept from the clean-up meanwhile
                pinned = persona[4:]
                jobs.pin(pinned)
            await ws.send_json({"status": "loading", "persona": chosen[0]})
            session = await run_in_threadpool(open_session, chosen[1], size, mode)
            loop = asyncio.get_running_loop()
            out: asyncio.Queue = asyncio.Queue()

            def post(item):  # from the runner's threads
                try:
                    loop.call_soon_threadsafe(out.put_nowait, item)
                except RuntimeError:  # the loop has closed: the server is stopping
                    pass

            feed = PushSource(fps=25, name="the Live page's camera")
            runner = threading.Thread(target=_run, args=(session, feed, post), name="facetex-studio-live", daemon=True)
            runner.start()
            await ws.send_json({"status": "ready", "engine": "facetex.live", "size": int(size), "mode": mode,
                                "max_in_flight": MAX_IN_FLIGHT, "frame_side": frame_side(size)})
            # the runner numbers the pushed frames 0, 1, ...: its record's index -> (page's id, arrival)
            pushed: dict = {}
            tasks = [asyncio.create_task(_receive(ws, feed, pushed, run_in_threadpool)),
                     asyncio.create_task(_reply(ws, out, pushed, run_in_threadpool))]
            done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            for t in done:
                t.result()  # the first error (or the page's disconnect) ends the session
        except WebSocketDisconnect:
            pass
        except FacetexError as e:
            await _close_with(ws, str(e).replace(str(config.workdir), "studio"))
        except Exception as e:  # noqa: BLE001 - the page shows one line, like the CLI's last resort
            await _close_with(ws, f"internal error: {type(e).__name__}: {e}")
        finally:
            # shielded: a cancelled handler (the page gone mid-await, a stopping server) must still stop
            # the session's processes and free the studio for the next page
            with anyio.CancelScope(shield=True):
                for t in tasks:
                    t.cancel()
                if feed is not None:
                    feed.close()  # the runner ends with the source
                await run_in_threadpool(_stop, session, runner)
                if pinned is not None:
                    jobs.unpin(pinned)
                busy.release()


def _stop(session, runner) -> None:
    """Wait for the runner's end, then stop the session's child processes."""
    if runner is not None:
        runner.join(timeout=30)
    if session is not None:
        session.close()


async def _receive(ws, feed, pushed: dict, in_thread) -> None:
    """The page's frames into the engine as they arrive (returns when the page closes the socket)."""
    n = 0
    while True:
        msg = await ws.receive()
        if msg["type"] == "websocket.disconnect":
            return
        arrival = time.perf_counter()
        fid, jpeg = _frame_message(msg.get("bytes"))
        frame = await in_thread(_decode, jpeg)
        pushed[n] = (fid, arrival)
        n += 1
        feed.push(frame)


async def _reply(ws, out: asyncio.Queue, pushed: dict, in_thread) -> None:
    """The engine's records to the page, in order: one binary message each (header and JPEG)."""
    while True:
        item = await out.get()
        if item is _END:
            raise BadInputError("the live engine stopped")
        if isinstance(item, BaseException):
            raise item
        index = item["index"]
        for k in [k for k in pushed if k < index]:  # dropped by the runner as stale: no reply
            del pushed[k]
        fid, arrival = pushed.pop(index, (None, None))
        jpeg = None if item["output"] is None else await in_thread(_encode, item["output"])
        server_ms = None if arrival is None else 1000 * (time.perf_counter() - arrival)
        await ws.send_bytes(reply_message(fid, item["kind"], server_ms, jpeg))


async def _close_with(ws, message: str) -> None:
    """Send ``{"error": message}`` and close; the page may have gone already."""
    try:
        await ws.send_json({"error": message})
        await ws.close()
    except Exception:  # noqa: BLE001 - nobody left to tell
        pass
