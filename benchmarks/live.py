"""Live puppetry (issue 26): a GRID clip played in real time through `facetex live`, through the
studio's hook (frames pushed one by one, JPEG in and out, as a WebSocket handler would), and the
offline `facetex puppet` on the same clip as the baseline of the same run.

    python benchmarks/live.py --data DATA --persona PERSONA.persona [--clip grid/bbaf2n.mpg] [--size 256]
                              [--seconds 10] [--out benchmarks/out/live]
    (or FACETEX_DATA instead of --data; the persona defaults to /work/personas/George_W_Bush.persona
    when that exists)

Targets (2 quiet cores, 256 px, 519-photo persona): sustained >= 25 fps, <= 5 % frames dropped, p95
latency (arrival -> output) <= 150 ms, first puppet frame <= 3 s after the start with a cached persona,
output frames matching the offline puppet within the puppetry bench's measures.

* **live CLI**: ``facetex live --source CLIP --loop N -o OUT.mp4 --json`` in a fresh process (the clip
  looped to ``--seconds``, played at its 25 fps): sustained fps (outputs after the first second of
  puppet frames), dropped frames (after the first puppet frame; before it, while the persona loads,
  counted apart), latency p50/p95, time from the command's start to its first puppet frame, CPU
  (user + system of the process and its tracking child over the wall time; 100 % = one core) and
  peak RSS (the largest process).
* **studio hook**: in this process, a LiveSession fed by a :class:`facetex.live.PushSource` at 25 fps
  with each frame JPEG-decoded before and the output JPEG-encoded after (what a WebSocket handler
  adds).
* **offline**: ``facetex puppet CLIP PERSONA --size N`` in a fresh process, wall time and fps.
* **quality**: the live output of the clip's first pass (in this process, frames kept by index) and the
  offline output, each measured as ``facetex bench puppet`` measures a run: mouth opening slope and
  Pearson r against the driver's (landmarks found on each panel upscaled to 720 px), cheek ΔE against
  the driver's cheeks, eye openness ratio; plus live against offline directly (mean |difference| in
  the face, cheek ΔE). A few frames are saved at 100 % as PNG (driver | live | offline).

The load average is printed before and after: on a shared machine times are upper bounds.
"""

from __future__ import annotations

import argparse
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

DEFAULT_PERSONA = Path("/work/personas/George_W_Bush.persona")


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


def studio_hook(persona: str, clip: str, size: int, loops: int, keep: bool = False) -> tuple[dict, dict]:
    """A LiveSession fed like the studio's WebSocket handler: JPEG frames pushed at the clip's rate;
    each output JPEG-encoded. Returns (report, {index: output frame} of the first pass when ``keep``)."""
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
    ap.add_argument("--persona", help="puppet .persona (default /work/personas/George_W_Bush.persona)")
    ap.add_argument("--clip", default="grid/bbaf2n.mpg", help="driver clip, relative to --data or a path")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--seconds", type=float, default=10.0, help="the clip is looped to at least this long")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "out" / "live"))
    ap.add_argument("--skip-studio", action="store_true")
    args = ap.parse_args(argv)
    data = args.data or os.environ.get("FACETEX_DATA")
    clip = Path(args.clip)
    if not clip.is_file():
        if not data:
            raise SystemExit("give --data DIR (with grid/) or set FACETEX_DATA, or a --clip path")
        clip = Path(data) / args.clip
    persona = args.persona or (str(DEFAULT_PERSONA) if DEFAULT_PERSONA.is_file() else None)
    if not persona:
        raise SystemExit("give --persona PERSONA.persona")
    from facetex.io import video_info
    from facetex.persona import read_persona_header

    info = video_info(clip)
    loops = max(1, int(np.ceil(args.seconds * (info["fps"] or 25) / max(info["n_frames"], 1))))
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
          f"{info['width']}x{info['height']}) looped {loops}x = {loops * info['n_frames'] / info['fps']:.1f} s; "
          f"size {args.size}; {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as tmp:
        live = cli_live(persona, str(clip), args.size, loops, Path(tmp) / "live.mp4")
        load_live = os.getloadavg()[0]
        offline_mp4 = out / "offline.mp4"
        off = cli_offline(persona, str(clip), args.size, offline_mp4)
        load_off = os.getloadavg()[0]
    studio, kept = studio_hook(persona, str(clip), args.size, 1 if args.skip_studio else loops, keep=True)
    load_studio = os.getloadavg()[0]
    q = quality(str(clip), kept, offline_mp4, args.size, out)
    after = _uptime()

    def row(name, r, load, cpu=None, rss=None, first=None):
        print(f"{name:28s} {r['sustained_fps']:>7.1f} {r['dropped_pct']:>8.1f} {r['dropped_startup']:>8d} "
              f"{r['latency_ms_p50']:>7.0f} {r['latency_ms_p95']:>7.0f} {first if first is not None else float('nan'):>8.2f} "
              f"{cpu if cpu is not None else float('nan'):>6.0f} {rss if rss is not None else float('nan'):>7.0f} "
              f"{load:>5.2f}")

    print(f"\n{'run':28s} {'fps':>7s} {'drop %':>8s} {'startup':>8s} {'p50 ms':>7s} {'p95 ms':>7s} {'first s':>8s} "
          f"{'CPU %':>6s} {'RSS MB':>7s} {'load':>5s}")
    row("facetex live (CLI, file)", live, load_live, live["cpu_pct"], live["peak_rss_mb"], live["start_to_first_s"])
    row("studio hook (push, JPEG)", studio, load_studio, studio["cpu_pct_this_process"], None,
        studio["first_puppet_s"])
    print(f"{'targets':28s} {'>= 25':>7s} {'<= 5':>8s} {'':>8s} {'':>7s} {'<= 150':>7s} {'<= 3':>8s}")
    print(f"\noffline `facetex puppet --size {args.size}` (same run): {off['frames']} frames in {off['wall_s']:.2f} s "
          f"= {off['fps_end_to_end']:.1f} fps end to end (load {load_off:.2f})")
    print(f"live stage medians (ms, CLI run): {json.dumps(live['stage_ms'])}; tracker detections {live['detections']}; "
          f"texture blends reused {live.get('texture_reused', 0)} of {live['puppet_frames']} frames; "
          f"set-up {json.dumps({k: v for k, v in live['timings'].items() if k.endswith('_s')})}")
    print(f"\nquality, {q['frames_compared']} frames of the first pass "
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
    (out / "report.json").write_text(json.dumps({"live_cli": live, "studio": studio, "offline": off, "quality": q,
                                                 "load_before": before, "load_after": after}, indent=1, default=str))


if __name__ == "__main__":
    main()
