"""Live puppetry (issue 26): a GRID clip played in real time through `facetex live`, through the real
studio (`facetex serve` in a child process, driven over the Live page's WebSocket protocol, and
optionally the Live page itself in headless Chromium), the engine alone in this process, and the
offline `facetex puppet` on the same clip as the baseline of the same run.

    python benchmarks/live.py --data DATA --persona PERSONA.persona [--clip grid/bbaf2n.mpg] [--size 256]
                              [--seconds 10] [--out benchmarks/out/live] [--browser] [--studio-only]
    (or FACETEX_DATA instead of --data and FACETEX_PERSONA instead of --persona; one of them is required)

Targets (2 quiet cores, 256 px, 519-photo persona): sustained >= 25 fps, <= 5 % frames dropped, p95
latency <= 150 ms, first puppet frame <= 3 s after the start with a cached persona, output frames
matching the offline puppet within the puppetry bench's measures.

* **live CLI**: ``facetex live --source CLIP --loop N -o OUT.mp4 --json`` in a fresh process (the clip
  looped to ``--seconds``, played at its 25 fps): sustained fps (outputs after the first second of
  puppet frames), dropped frames (after the first puppet frame; before it, while the persona loads,
  counted apart), latency p50/p95 (arrival -> output), time from the command's start to its first
  puppet frame, CPU (user + system of the process and its tracking child over the wall time; 100 % =
  one core) and peak RSS (the largest process).
* **studio, WebSocket client**: ``facetex serve --port 0`` on a free localhost port in a child process
  (the persona offered through ``--personas``), and a client (the ``websockets`` package) speaking the
  Live page's protocol (facetex/studio/live.py): it connects, waits for "ready", then plays the clip
  (looped) at 25 fps in real time until ``--seconds`` after the first second of puppet frames, each frame JPEG 85 at the ``frame_side`` the server asks for (as the page
  scales its camera frames), a 4-byte id before it, at most ``max_in_flight`` (4) unanswered (a frame
  beyond is held back, as the page does). Measured in the client's clock: fps of the puppet replies
  (after the first second of them), dropped (the camera frames from the first puppet frame on without
  a reply: held back by the client or dropped by the engine), latency p50/p95 (send -> reply of the
  same id), time from the connect to the first puppet frame; CPU and peak RSS (the largest process)
  of the server's process tree (the server and its tracking and rendering children), sampled from
  /proc. The client encodes the clip's JPEGs once, before playing (the page encodes each frame).
* **studio, Chromium Live page** (``--browser``): the studio as above and its Live page in headless
  Chromium (Playwright, Debian's chromium), the fake camera playing the clip as a .y4m; the page's own
  counters (``window.liveStats``) over ``--seconds`` after the first second of puppet frames; dropped =
  the camera's frames (25 fps over the window) without an output; CPU of the server's and of the
  browser's processes.
* **engine in-process (no server)**: in this process, a LiveSession fed by a
  :class:`facetex.live.PushSource` at 25 fps with each frame JPEG-decoded before and the output
  JPEG-encoded after: what the engine gives without the server, the socket and the client.
* **offline**: ``facetex puppet CLIP PERSONA --size N`` in a fresh process, wall time and fps.
* **quality**: the studio's replies (JPEG, decoded; for each of the clip's frames the first puppet
  frame made from it, whichever pass of the loop: the start-up may outlast the first) and the offline output,
  each measured as ``facetex bench puppet`` measures a run: mouth opening slope and Pearson r against
  the driver's (landmarks found on each panel upscaled to 720 px), cheek ΔE against the driver's
  cheeks, eye openness ratio; plus live against offline directly (mean |difference| in the face,
  cheek ΔE). A few frames are saved at 100 % as PNG (driver | live | offline).

The load average is printed before and after: on a shared machine times are upper bounds.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

def _uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    except OSError:
        return "load average: %.2f, %.2f, %.2f" % os.getloadavg()


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def cli_live(persona: str, clip: str, size: int, loops: int, out: Path) -> dict:
    exe = [sys.executable, "-m", "facetex"]
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    cmd = exe + ["live", "--puppet", persona, "--source", clip, "--loop", str(loops), "--size", str(size),
                 "-o", str(out), "--overwrite", "--json", "-q"]
    cpu0, t_unix, t0 = _children_cpu(), time.time(), time.perf_counter()
    res = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if res.returncode:
        raise SystemExit(f"facetex live failed: {res.stderr.strip()}")
    rep = json.loads(res.stdout)
    rep["cpu_pct"] = 100.0 * (_children_cpu() - cpu0) / wall
    rep["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    rep["start_to_first_s"] = rep["first_puppet_unix"] - t_unix if rep.get("first_puppet_unix") else None
    rep["wall_process_s"] = wall
    return rep


def cli_offline(persona: str, clip: str, size: int, out: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]), OMP_NUM_THREADS="2")
    cmd = [sys.executable, "-m", "facetex", "puppet", clip, persona, "-o", str(out), "--size", str(size),
           "--overwrite", "--json", "-q"]
    t0 = time.perf_counter()
    res = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if res.returncode:
        raise SystemExit(f"facetex puppet failed: {res.stderr.strip()}")
    rep = json.loads(res.stdout)
    rep["wall_s"] = wall
    rep["fps_end_to_end"] = rep["frames"] / wall
    return rep


# -- the real studio: `facetex serve` in a child process, played through its Live WebSocket ---------------
def _proc_table() -> dict:
    """{pid: (ppid, cpu seconds (user + system))} of every process, from /proc."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            f = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):  # gone meanwhile
            continue
        out[int(stat.parent.name)] = (int(f[1]), (int(f[11]) + int(f[12])) / tick)
    return out


def _subtree(table: dict, root: int, exclude=()) -> set:
    kids: dict = {}
    for pid, (ppid, _) in table.items():
        kids.setdefault(ppid, []).append(pid)
    out, todo = set(), [root]
    while todo:
        p = todo.pop()
        if p in exclude or p in out:
            continue
        out.add(p)
        todo.extend(kids.get(p, ()))
    return out


class TreeSampler:
    """CPU time (user + system) and peak RSS of a process and its descendants, sampled from /proc on
    a thread every ``period`` s (a child that ends between two samples loses at most its last period;
    ``exclude``: subtrees left out, e.g. the studio's when sampling the browser under this process)."""

    def __init__(self, root: int, *, exclude=(), period: float = 0.2, skip_root: bool = False):
        self.root, self.exclude, self.period, self.skip_root = root, set(exclude), period, skip_root
        self.first: dict = {}
        self.last: dict = {}
        self.hwm_kb = 0  # the largest process's peak (VmHWM)
        self.tree_kb = 0  # the largest sum of the tree's RSS at one sample
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _sample(self, initial: bool = False) -> None:
        table = _proc_table()
        pids = _subtree(table, self.root, self.exclude)
        if self.skip_root:
            pids.discard(self.root)
        tree = 0
        for pid in pids:
            cpu = table[pid][1]
            self.first.setdefault(pid, cpu if initial else 0.0)  # a process started meanwhile: from 0
            self.last[pid] = cpu
            try:
                status = Path(f"/proc/{pid}/status").read_text()
            except OSError:
                continue
            for line in status.splitlines():
                if line.startswith("VmHWM:"):
                    self.hwm_kb = max(self.hwm_kb, int(line.split()[1]))
                elif line.startswith("VmRSS:"):
                    tree += int(line.split()[1])
        self.tree_kb = max(self.tree_kb, tree)

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            self._sample()

    def start(self) -> "TreeSampler":
        self._sample(initial=True)
        self.t0 = time.perf_counter()
        self._thread.start()
        return self

    def stop(self) -> dict:
        self._stop.set()
        self._thread.join()
        self._sample()
        wall = time.perf_counter() - self.t0
        cpu = sum(self.last[p] - self.first[p] for p in self.last)
        return {"cpu_s": round(cpu, 2), "wall_s": round(wall, 2), "cpu_pct": round(100 * cpu / wall, 1),
                "peak_rss_mb": round(self.hwm_kb / 1024, 1), "peak_tree_rss_mb": round(self.tree_kb / 1024, 1)}


def start_studio(persona: str, workdir: Path, pythonpath=None) -> tuple:
    """``facetex serve --port 0 --json`` in a child process, offering ``persona`` (a symlink in a
    --personas folder of its own): (process, url, persona id)."""
    import urllib.request

    pdir = workdir / "personas"
    pdir.mkdir(parents=True, exist_ok=True)
    link = pdir / Path(persona).name
    if not link.exists():
        link.symlink_to(Path(persona).resolve())
    env = dict(os.environ, PYTHONPATH=str(pythonpath or Path(__file__).resolve().parents[1]))
    proc = subprocess.Popen([sys.executable, "-m", "facetex", "serve", "--port", "0", "--json", "--workdir",
                             str(workdir / "work"), "--personas", str(pdir)], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    lines = []
    while True:
        line = proc.stdout.readline()
        if not line:
            raise SystemExit(f"facetex serve exited {proc.wait()}: {proc.stderr.read().strip()}")
        lines.append(line)
        if line.rstrip() == "}":
            break
    url = json.loads("".join(lines))["url"]
    with urllib.request.urlopen(url + "api/personas", timeout=30) as r:
        ids = {p["name"]: p["id"] for p in json.loads(r.read())}
    return proc, url, ids[Path(persona).stem]


def stop_studio(proc) -> None:
    import signal

    proc.send_signal(signal.SIGINT)  # as Ctrl-C: uvicorn shuts down, the jobs and sessions stop
    try:
        proc.wait(30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


#: the reply header of the Live protocol (facetex/studio/live.py): id, kind, flags, pad, server ms
_REPLY = ">IBBHf"
_KINDS = {0: "warmup", 1: "puppet", 2: "lost"}


def _jpeg(frame: np.ndarray, side: int | None) -> bytes:
    """A camera frame as the Live page sends it: scaled down to ``side`` (its longer side), JPEG 85."""
    h, w = frame.shape[:2]
    if side and max(w, h) > side:
        k = side / max(w, h)
        frame = cv2.resize(frame, (round(w * k), round(h * k)), interpolation=cv2.INTER_AREA)
    return cv2.imencode(".jpg", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])[1].tobytes()


async def _play(url: str, persona_id: str, frames: list, fps: float, seconds: float, size: int, keep: bool,
                settle: float = 1.0) -> dict:
    """The Live page's protocol from a client: connect, wait for "ready", send the clip's frames (looped)
    at ``fps`` in real time (4-byte id + JPEG, at most ``max_in_flight`` unanswered: a frame beyond is
    held back, as the page does) until ``settle`` + ``seconds`` after the first puppet frame, read the
    replies; times in this process's clock."""
    import struct

    import websockets

    n = len(frames)
    ws_url = url.replace("http://", "ws://", 1) + f"api/live?persona={persona_id}&size={size}&mode=composite"
    t_connect = time.perf_counter()
    offered, sent_at, in_flight, replies, kept = [], {}, {}, {}, {}
    async with websockets.connect(ws_url, max_size=16 * 2**20) as ws:
        while True:
            m = json.loads(await ws.recv())
            if "error" in m:
                raise SystemExit(f"the studio's Live socket: {m['error']}")
            if m.get("status") == "ready":
                break
        t_ready = time.perf_counter()
        side, max_in_flight = m.get("frame_side"), m.get("max_in_flight", 4)
        jpegs = [_jpeg(f, side) for f in frames]  # the page encodes each frame as it comes; done ahead here
        done = asyncio.Event()
        first = []

        async def sender():
            t0 = time.perf_counter()
            for k in range(int((seconds + settle + 60) * fps)):  # at most a minute of start-up
                if first and time.perf_counter() >= first[0] + settle + seconds:
                    break
                wait = t0 + k / fps - time.perf_counter()
                if wait > 0:
                    await asyncio.sleep(wait)
                now = time.perf_counter()
                offered.append((k, now))
                if len(in_flight) >= max_in_flight:
                    continue  # held back: the next camera frame is newer
                in_flight[k] = sent_at[k] = now
                await ws.send(k.to_bytes(4, "big") + jpegs[k % n])
            done.set()

        async def receiver():
            while True:
                msg = await ws.recv()
                now = time.perf_counter()
                if isinstance(msg, str):
                    m = json.loads(msg)
                    raise SystemExit(f"the studio's Live socket: {m.get('error', m)}")
                fid, kind, _, _, server_ms = struct.unpack_from(_REPLY, msg)
                for k in list(in_flight):  # replies come in order: older unanswered ids were dropped
                    if k == fid:
                        break
                    del in_flight[k]
                in_flight.pop(fid, None)
                replies[fid] = (_KINDS.get(kind, "?"), now, server_ms)
                if kind == 1 and not first:
                    first.append(now)
                if keep and kind == 1:  # the first puppet frame of each of the clip's frames, whichever pass
                    kept.setdefault(fid % n, msg[struct.calcsize(_REPLY):])
                if done.is_set() and not in_flight:
                    return

        cpu0 = time.process_time()
        send = asyncio.create_task(sender())
        recv = asyncio.create_task(receiver())
        await send
        try:
            await asyncio.wait_for(recv, timeout=3.0)  # the replies of the last frames
        except asyncio.TimeoutError:
            pass
        client_cpu = time.process_time() - cpu0
    return {"t_connect": t_connect, "t_ready": t_ready, "offered": offered, "sent_at": sent_at,
            "replies": replies, "kept": kept, "client_cpu_s": client_cpu, "frame_side": side}


def _client_stats(r: dict, settle: float = 1.0) -> dict:
    """fps, dropped, latency of a played stream in the client's clock, as LiveStats.summary counts them
    (fps and latency from ``settle`` s after the first puppet frame; dropped from the first puppet frame)."""
    replies, sent_at = r["replies"], r["sent_at"]
    puppets = sorted((t, fid) for fid, (kind, t, _) in replies.items() if kind == "puppet")
    if not puppets:
        raise SystemExit("the studio sent no puppet frame")
    first = puppets[0][0]
    out = np.array([t for t, _ in puppets])
    keep = out >= first + settle
    if keep.sum() < 10:
        keep[:] = True
    o = out[keep]
    lat = np.array([1000 * (t - sent_at[fid]) for t, fid in puppets])[keep]
    after = [k for k, t in r["offered"] if t >= first]
    before = [k for k, t in r["offered"] if t < first]
    answered = lambda k: k in replies and replies[k][0] != "warmup"  # noqa: E731
    held = sum(1 for k in after if k not in sent_at)
    dropped = sum(1 for k in after if not answered(k))
    server = [s for kind, _, s in replies.values() if kind == "puppet"]
    return {"camera_frames": len(r["offered"]), "sent": len(sent_at), "puppet_frames": len(puppets),
            "lost_frames": sum(1 for v in replies.values() if v[0] == "lost"),
            "warmup_frames": sum(1 for v in replies.values() if v[0] == "warmup"),
            "sustained_fps": round(float((len(o) - 1) / (o[-1] - o[0])), 2) if len(o) > 1 else 0.0,
            "dropped": dropped, "held_back": held, "dropped_by_server": dropped - held,
            "dropped_pct": round(100.0 * dropped / max(len(after), 1), 2),
            "dropped_startup": sum(1 for k in before if not answered(k)),
            "latency_ms_p50": round(float(np.percentile(lat, 50)), 1),
            "latency_ms_p95": round(float(np.percentile(lat, 95)), 1), "latency_ms_max": round(float(lat.max()), 1),
            "server_ms_p50": round(float(np.median(server)), 1), "server_ms_p95": round(float(np.percentile(server, 95)), 1),
            "ready_s": round(r["t_ready"] - r["t_connect"], 3), "first_puppet_s": round(first - r["t_connect"], 3),
            "frame_side": r["frame_side"]}


def studio_ws(persona: str, clip: str, size: int, seconds: float, workdir: Path, keep: bool = False,
              pythonpath=None) -> tuple:
    """The real studio (``facetex serve`` in a child process) driven through the Live page's WebSocket
    protocol by a client playing the clip at its rate: (report, {index: output frame} of the first pass)."""
    from facetex.io import iter_video_frames, video_info

    fps = video_info(clip)["fps"] or 25.0
    frames = list(iter_video_frames(clip, uint8=True))
    proc, url, pid = start_studio(persona, workdir, pythonpath)
    try:
        sampler = TreeSampler(proc.pid).start()
        r = asyncio.run(_play(url, pid, frames, fps, seconds, size, keep))
        server = sampler.stop()
    finally:
        stop_studio(proc)
    rep = _client_stats(r)
    rep.update(server_cpu_pct=server["cpu_pct"], server_peak_rss_mb=server["peak_rss_mb"],
               server_peak_tree_rss_mb=server["peak_tree_rss_mb"], server_cpu_s=server["cpu_s"],
               client_cpu_pct=round(100 * r["client_cpu_s"] / server["wall_s"], 1), wall_s=server["wall_s"])
    kept = {i: cv2.cvtColor(cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
            for i, b in r["kept"].items()}
    return rep, kept


def _write_y4m(path: Path, frames: list, fps: int) -> Path:
    """A YUV4MPEG2 clip for Chromium's fake camera (it loops it)."""
    h, w = frames[0].shape[:2]
    with open(path, "wb") as fh:
        fh.write(f"YUV4MPEG2 W{w} H{h} F{fps}:1 Ip A1:1 C420jpeg\n".encode())
        for f in frames:
            fh.write(b"FRAME\n" + cv2.cvtColor(f, cv2.COLOR_RGB2YUV_I420).tobytes())
    return path


def studio_browser(persona: str, clip: str, size: int, seconds: float, workdir: Path, pythonpath=None) -> dict:
    """The studio's Live page in headless Chromium (Playwright; Debian's chromium), its fake camera
    playing the clip (a .y4m, looped); the page's own counters (window.liveStats) over ``seconds``
    after the first second of puppet frames; CPU of the server's and of the browser's processes."""
    import shutil

    from playwright.sync_api import sync_playwright

    from facetex.io import iter_video_frames, video_info

    exe = next((shutil.which(b) for b in ("chromium", "chromium-browser", "google-chrome") if shutil.which(b)), None)
    if exe is None:
        raise SystemExit("--browser needs Chromium (apt-get install chromium) and Playwright")
    fps = int(round(video_info(clip)["fps"] or 25))
    workdir.mkdir(parents=True, exist_ok=True)
    y4m = _write_y4m(workdir / "camera.y4m", list(iter_video_frames(clip, uint8=True)), fps)
    proc, url, pid = start_studio(persona, workdir, pythonpath)
    try:
        with sync_playwright() as p:
            b = p.chromium.launch(executable_path=exe, args=[
                "--no-sandbox", "--disable-gpu", "--use-fake-device-for-media-stream",
                "--use-fake-ui-for-media-stream", f"--use-file-for-fake-video-capture={y4m}"])
            try:
                pg = b.new_page(viewport={"width": 1200, "height": 860})
                pg.goto(url + "live")
                pg.wait_for_function("document.querySelectorAll('#persona option').length > 0")
                pg.select_option("#persona", pid)
                pg.fill("#size", str(size))
                server = TreeSampler(proc.pid).start()
                browser = TreeSampler(os.getpid(), exclude={proc.pid}, skip_root=True).start()
                pg.evaluate("window.tClick = performance.now()")
                pg.click("#start")
                pg.wait_for_function("window.liveStats.first != null", timeout=60_000)
                first_s = pg.evaluate("(liveStats.first - tClick) / 1000")
                pg.wait_for_timeout(1000)  # settle, as the other rows
                snap = ("({sent: liveStats.sent, received: liveStats.received, dropped: liveStats.dropped, "
                        "held: liveStats.held, lost: liveStats.lost, n: liveStats.latencies.length, "
                        "lat: liveStats.latencies.slice(), now: performance.now()})")
                a = pg.evaluate(snap)
                pg.wait_for_timeout(int(1000 * seconds))
                z = pg.evaluate(snap)
                srv, brw = server.stop(), browser.stop()
                pg.click("#stop")
                pg.close()
            finally:
                b.close()
    finally:
        stop_studio(proc)
    dt = (z["now"] - a["now"]) / 1000
    d = {k: z[k] - a[k] for k in ("sent", "received", "dropped", "held", "lost")}
    lat = np.array(z["lat"][a["n"]:]) if z["n"] >= a["n"] else np.array(z["lat"])
    # the camera's frames over the window at its rate: those without an output were dropped, whether the
    # engine dropped them, the page held them back, or the page never saw them (a busy main thread)
    camera = fps * dt
    return {"sustained_fps": round(d["received"] / dt, 2), "camera_frames": round(camera), **d,
            "dropped_pct": round(max(0.0, 100.0 * (1 - (d["received"] + d["lost"]) / camera)), 2),
            "latency_ms_p50": round(float(np.percentile(lat, 50)), 1) if len(lat) else None,
            "latency_ms_p95": round(float(np.percentile(lat, 95)), 1) if len(lat) else None,
            "first_puppet_s": round(first_s, 3), "window_s": round(dt, 2),
            "server_cpu_pct": srv["cpu_pct"], "server_peak_rss_mb": srv["peak_rss_mb"],
            "browser_cpu_pct": brw["cpu_pct"], "browser_peak_tree_rss_mb": brw["peak_tree_rss_mb"]}


def engine_in_process(persona: str, clip: str, size: int, loops: int, keep: bool = False) -> tuple[dict, dict]:
    """The engine alone, in this process (not the studio): a LiveSession fed by a PushSource at the
    clip's rate, each frame JPEG-decoded before and the output JPEG-encoded after, as the studio's
    handler does. Returns (report, {index: output frame} of the first pass when ``keep``)."""
    from facetex.io import iter_video_frames, video_info
    from facetex.live import LiveSession, PushSource, run_live

    fps = video_info(clip)["fps"] or 25.0
    jpegs = [cv2.imencode(".jpg", cv2.cvtColor(f, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 90])[1]
             for f in iter_video_frames(clip, uint8=True)]
    n = len(jpegs)
    session = LiveSession(persona, size=size)
    session.wait_loaded()  # the studio opens the session when the page asks for it, before the camera starts
    feed = PushSource(fps=fps, name="studio feed")
    kept: dict = {}
    sent = [0]

    def on_frame(rec):
        if rec["output"] is not None:
            cv2.imencode(".jpg", cv2.cvtColor(rec["output"], cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 90])
            sent[0] += 1
            if keep and rec["index"] < n:
                kept[rec["index"]] = rec["output"]

    def pusher():
        t0 = time.perf_counter()
        for k in range(loops * n):
            wait = t0 + k / fps - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
            frame = cv2.cvtColor(cv2.imdecode(jpegs[k % n], cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
            feed.push(frame, k / fps)
        feed.close()

    cpu0 = time.process_time()
    t0 = time.perf_counter()
    th = threading.Thread(target=pusher, daemon=True)
    th.start()
    with session:
        rep = run_live(feed, session=session, on_frame=on_frame)
    th.join()
    rep["cpu_pct_this_process"] = 100.0 * (time.process_time() - cpu0) / (time.perf_counter() - t0)
    return rep, kept


def _landmarks(image_u8: np.ndarray):
    from facetex.bench._puppet_clip import _frame_measures

    p, _ = _frame_measures(image_u8.astype(np.float32) / 255.0, descriptor=False)
    return p


def quality(clip: str, live: dict, offline_path: Path, size: int, out: Path) -> dict:
    """Per-frame measures of the live and offline outputs against the driver (module doc)."""
    from facetex.bench.puppet_measures import (cheek_delta_e, cheek_mask, eye_aspect_ratio, eye_openness_ratio,
                                               mouth_slope)
    from facetex.bench.puppet_measures import _pearson
    from facetex.io import iter_video_frames
    from facetex.puppet.driver import mouth_opening

    offline = list(iter_video_frames(offline_path, uint8=True))
    H, W = offline[0].shape[:2]
    driver = [cv2.resize(f, (W, H), interpolation=cv2.INTER_AREA) for f in iter_video_frames(clip, uint8=True)]
    live = {i: f if f.shape == offline[0].shape else cv2.resize(f, (W, H), interpolation=cv2.INTER_AREA)
            for i, f in live.items()}  # the studio's frames may differ by a pixel (the page's scaled camera frame)
    idx = [i for i in sorted(live) if i < len(offline)]
    n = len(driver)
    P = {k: np.full((n, 68, 2), np.nan) for k in ("driver", "live", "offline")}
    de = {k: np.full(n, np.nan) for k in ("live", "offline", "live_vs_offline")}
    diff = []
    for i in idx:
        frames = {"driver": driver[i], "live": live[i], "offline": offline[i]}
        for k, f in frames.items():
            p = _landmarks(f)
            if p is not None:
                P[k][i] = p
        if not np.isfinite(P["driver"][i]).all():
            continue
        m = cheek_mask(P["driver"][i], (H, W))
        f32 = {k: v.astype(np.float32) / 255 for k, v in frames.items()}
        de["live"][i] = cheek_delta_e(f32["live"], f32["driver"], m)
        de["offline"][i] = cheek_delta_e(f32["offline"], f32["driver"], m)
        de["live_vs_offline"][i] = cheek_delta_e(f32["live"], f32["offline"], m)
        hull = cv2.convexHull(P["driver"][i].astype(np.float32)).astype(np.int32)
        face = np.zeros((H, W), np.uint8)
        cv2.fillConvexPoly(face, hull, 1)
        diff.append(np.abs(live[i].astype(float) - offline[i].astype(float))[face > 0].mean())
    op = {k: mouth_opening(v) for k, v in P.items()}
    ear = {k: eye_aspect_ratio(v) for k, v in P.items()}
    res = {"frames_compared": len(idx), "live_vs_offline_face_mad": float(np.mean(diff)) if diff else None,
           "live_vs_offline_cheek_de": float(np.nanmedian(de["live_vs_offline"]))}
    for k in ("live", "offline"):
        res[k] = {"mouth_slope": mouth_slope(op["driver"], op[k]), "mouth_r": _pearson(op["driver"], op[k]),
                  "cheek_de": float(np.nanmedian(de[k])), "eye_ratio": eye_openness_ratio(ear["driver"], ear[k])}
    # frames at 100 %: driver | live | offline, at a closed, a middle and the widest mouth opening
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("frame*_driver_live_offline.png"):
        old.unlink()
    ok = [i for i in idx if np.isfinite(op["driver"][i])]
    if ok:
        order = sorted(ok, key=lambda i: op["driver"][i])
        picks = sorted({order[0], order[len(order) // 2], order[-1], ok[len(ok) // 3]})
        for i in picks:
            row = np.concatenate([driver[i], live[i], offline[i]], axis=1)
            cv2.imwrite(str(out / f"frame{i:03d}_driver_live_offline.png"), cv2.cvtColor(row, cv2.COLOR_RGB2BGR))
        # consecutive frames of the live output (jitter / flicker): mean |frame t - frame t-1| in the face
        steps = {k: [] for k in ("live", "offline", "driver")}
        src = {"live": live, "offline": offline, "driver": driver}
        for i in idx[1:]:
            if i - 1 in live and np.isfinite(P["driver"][i]).all():
                hull = cv2.convexHull(P["driver"][i].astype(np.float32)).astype(np.int32)
                face = np.zeros((H, W), np.uint8)
                cv2.fillConvexPoly(face, hull, 1)
                for k in steps:
                    steps[k].append(np.abs(src[k][i].astype(float) - src[k][i - 1].astype(float))[face > 0].mean())
        res["frame_step_mad"] = {k: float(np.mean(v)) if v else None for k, v in steps.items()}
        res["pngs"] = str(out)
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", help="data folder with grid/ (default $FACETEX_DATA)")
    ap.add_argument("--persona", help="puppet .persona (required; or $FACETEX_PERSONA)")
    ap.add_argument("--clip", default="grid/bbaf2n.mpg", help="driver clip, relative to --data or a path")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--seconds", type=float, default=10.0, help="the clip is looped to at least this long")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "out" / "live"))
    ap.add_argument("--skip-studio", action="store_true", help="no studio row (nor the in-process engine row)")
    ap.add_argument("--browser", action="store_true",
                    help="also the Live page in headless Chromium (Playwright), its fake camera playing the clip")
    ap.add_argument("--studio-only", action="store_true",
                    help="only the studio rows (no CLI, offline or quality runs)")
    ap.add_argument("--studio-code", metavar="DIR",
                    help="PYTHONPATH of the studio's server (default: this checkout), to compare two versions")
    args = ap.parse_args(argv)
    data = args.data or os.environ.get("FACETEX_DATA")
    clip = Path(args.clip)
    if not clip.is_file():
        if not data:
            raise SystemExit("give --data DIR (with grid/) or set FACETEX_DATA, or a --clip path")
        clip = Path(data) / args.clip
    persona = args.persona or os.environ.get("FACETEX_PERSONA")
    if not persona:
        raise SystemExit("give --persona PERSONA.persona (or set FACETEX_PERSONA): the puppet the clip drives")
    if not Path(persona).is_file():
        raise SystemExit(f"--persona {persona}: no such file")
    from facetex.io import video_info
    from facetex.persona import read_persona_header

    info = video_info(clip)
    loops = max(1, int(np.ceil(args.seconds * (info["fps"] or 25) / max(info["n_frames"], 1))))
    seconds = loops * info["n_frames"] / (info["fps"] or 25)
    n_photos = read_persona_header(persona).get("n_photos")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # "a cached persona": the first session of a .persona file writes its rebuilt texture stacks to
    # facetex's cache folder; later sessions map them (facetex.persona._stack_cache)
    from facetex.live import LiveSession

    t0 = time.perf_counter()
    with LiveSession(persona, size=args.size, background=False) as s:
        primed = s.timings.get("stack_cache", "none")
    print(f"persona stack cache: {primed} ({time.perf_counter() - t0:.1f} s)")
    before = _uptime()
    print(f"before: {before}")
    print(f"persona {persona} ({n_photos} photos); clip {clip} ({info['n_frames']} frames at {info['fps']:g} fps, "
          f"{info['width']}x{info['height']}) looped {loops}x = {seconds:.1f} s; "
          f"size {args.size}; {os.cpu_count()} cores")
    rows, report = [], {}
    studio = kept = None
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if not args.studio_only:
            live = cli_live(persona, str(clip), args.size, loops, tmp / "live.mp4")
            report["live_cli"] = live
            rows.append(("facetex live (CLI, file)", live, os.getloadavg()[0], live["cpu_pct"], live["peak_rss_mb"],
                         live["start_to_first_s"]))
            offline_mp4 = out / "offline.mp4"
            off = cli_offline(persona, str(clip), args.size, offline_mp4)
            report["offline"] = off
            load_off = os.getloadavg()[0]
        if not args.skip_studio:
            studio, kept = studio_ws(persona, str(clip), args.size, seconds, tmp / "ws", keep=True,
                                     pythonpath=args.studio_code)
            report["studio_ws"] = studio
            rows.append(("studio, WebSocket client", studio, os.getloadavg()[0], studio["server_cpu_pct"],
                         studio["server_peak_rss_mb"], studio["first_puppet_s"]))
            if args.browser:
                page = studio_browser(persona, str(clip), args.size, seconds, tmp / "browser", args.studio_code)
                report["studio_browser"] = page
                rows.append(("studio, Chromium Live page", page, os.getloadavg()[0], page["server_cpu_pct"],
                             page["server_peak_rss_mb"], page["first_puppet_s"]))
            if not args.studio_only:
                engine, _ = engine_in_process(persona, str(clip), args.size, loops)
                report["engine_in_process"] = engine
                rows.append(("engine in-process (no server)", engine, os.getloadavg()[0], None, None,
                             engine["first_puppet_s"]))
    q = None
    if kept and not args.studio_only:
        q = quality(str(clip), kept, offline_mp4, args.size, out)
        report["quality"] = q
    after = _uptime()

    def num(v, fmt, width):
        return f"{format(v, fmt) if v is not None else '':>{width}s}"

    print(f"\n{'run':30s} {'fps':>6s} {'drop %':>7s} {'p50 ms':>7s} {'p95 ms':>7s} {'first s':>8s} "
          f"{'CPU %':>6s} {'RSS MB':>7s} {'load':>5s}")
    for name, r, load, cpu, rss, first in rows:
        print(f"{name:30s} {num(r['sustained_fps'], '.1f', 6)} {num(r['dropped_pct'], '.1f', 7)} "
              f"{num(r['latency_ms_p50'], '.0f', 7)} {num(r['latency_ms_p95'], '.0f', 7)} {num(first, '.2f', 8)} "
              f"{num(cpu, '.0f', 6)} {num(rss, '.0f', 7)} {load:>5.2f}")
    print(f"{'targets':30s} {'>= 25':>6s} {'<= 5':>7s} {'':>7s} {'<= 150':>7s} {'<= 3':>8s}")
    print("(CLI: CPU and RSS of the command and its children, first frame after the command's start; studio rows: "
          "of the server's process tree, first frame after the socket's connect / the page's Start; "
          "latency in the client's clock, send to receive)")
    if studio:
        print(f"studio WebSocket client: {studio['camera_frames']} camera frames, {studio['sent']} sent, "
              f"{studio['held_back']} held back (4 in flight), {studio['dropped_by_server']} dropped by the engine "
              f"after the first puppet frame, {studio['dropped_startup']} before it; ready after {studio['ready_s']:.2f} s; "
              f"server ms p50/p95 {studio['server_ms_p50']}/{studio['server_ms_p95']}; frames sent at "
              f"{studio['frame_side'] or 'full'} px; client CPU {studio['client_cpu_pct']:.0f} %; "
              f"server tree peak RSS {studio['server_peak_tree_rss_mb']:.0f} MB")
    if "studio_browser" in report:
        page = report["studio_browser"]
        print(f"Chromium page: {page['received']} puppet frames in {page['window_s']:.1f} s, sent {page['sent']}, "
              f"dropped {page['dropped']}, held {page['held']}, lost {page['lost']}; browser CPU "
              f"{page['browser_cpu_pct']:.0f} %, browser RSS {page['browser_peak_tree_rss_mb']:.0f} MB")
    if "offline" in report:
        live = report["live_cli"]
        print(f"\noffline `facetex puppet --size {args.size}` (same run): {off['frames']} frames in {off['wall_s']:.2f} s "
              f"= {off['fps_end_to_end']:.1f} fps end to end (load {load_off:.2f})")
        print(f"live stage medians (ms, CLI run): {json.dumps(live['stage_ms'])}; tracker detections {live['detections']}; "
              f"texture blends reused {live.get('texture_reused', 0)} of {live['puppet_frames']} frames; "
              f"set-up {json.dumps({k: v for k, v in live['timings'].items() if k.endswith('_s')})}")
    if q:
        print(f"\nquality, {q['frames_compared']} of the clip's frames, live = the studio's JPEG replies "
              f"(bench puppet targets: slope 0.8-1.3, r >= 0.85, cheek dE <= 8, eye ratio >= 0.8):")
        print(f"{'':10s} {'slope':>7s} {'r':>6s} {'cheek dE':>9s} {'eye ratio':>10s}")
        for k in ("live", "offline"):
            m = q[k]
            print(f"{k:10s} {m['mouth_slope']:>7.2f} {m['mouth_r']:>6.2f} {m['cheek_de']:>9.2f} {m['eye_ratio']:>10.2f}")
        print(f"live vs offline: mean |difference| in the face {q['live_vs_offline_face_mad']:.1f}/255, cheek dE "
              f"{q['live_vs_offline_cheek_de']:.2f}; frame-to-frame change in the face (mean |I_t - I_t-1|): "
              + ", ".join(f"{k} {v:.2f}" for k, v in q.get("frame_step_mad", {}).items() if v is not None))
        print(f"PNGs (driver | live | offline, 100 %): {q.get('pngs')}")
    print(f"\nbefore: {before}\nafter:  {after}")
    report.update(load_before=before, load_after=after)
    (out / "report.json").write_text(json.dumps(report, indent=1, default=str))


if __name__ == "__main__":
    main()
