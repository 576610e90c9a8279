"""``facetex live --puppet PERSON.persona [--source 0|/dev/videoN|URL|FILE] [-o OUT.mp4]`` — live puppetry
(issue 26): frames processed as they arrive, stale frames dropped, output to a window or a file."""

from __future__ import annotations

import sys

from ._common import (add_json, add_output, add_overwrite, add_quiet, add_seed_device, bounded_int, finite_float,
                      positive_int, print_json)


def register(sub) -> None:
    p = sub.add_parser("live", help="drive a persona's face live from a camera, a stream or a video played in real time")
    p.add_argument("puppet_pos", nargs="?", metavar="PUPPET", help="puppet .persona file (facetex persona build)")
    p.add_argument("--puppet", help="the same as PUPPET")
    p.add_argument("--source", default="0",
                   help="camera index (default 0), /dev/videoN, a URL (rtsp://, http://, ...) or a video file "
                        "(played at its own frame rate)")
    add_output(p, metavar="OUT.mp4", help="also write the output to an H.264 .mp4 (at the source's frame rate; "
                                          "without -o the output is shown in a window)")
    p.add_argument("--window", action="store_true", help="show the output in a window (the default without -o)")
    p.add_argument("--size", type=bounded_int(32, 4096), default=256,
                   help="longer side of the output frame in px, 32..4096 (default %(default)s)")
    p.add_argument("--mode", choices=("composite", "face"), default="composite",
                   help="composite: the puppet put into the driver's frame (default); face: the puppet face alone")
    p.add_argument("--lost", choices=("driver", "last"), default="driver",
                   help="what a frame without a usable face shows: the driver's own frame (a plain panel in face "
                        "mode; default) or the last puppet frame")
    p.add_argument("--max-frames", type=positive_int, help="stop after N source frames")
    p.add_argument("--duration", type=finite_float(0.0, None, open_lo=True), metavar="SECONDS",
                   help="stop after this many seconds")
    p.add_argument("--loop", type=bounded_int(1, 10_000), default=1, help="play a video file N times (default 1)")
    p.add_argument("--workers", choices=("process", "thread"), default="process",
                   help="track the face and render the puppet in two child processes beside this one's mesh and "
                        "texture work (default), or all in this process (threads)")
    add_seed_device(p)
    add_overwrite(p)
    add_quiet(p)
    add_json(p, "the run's report (fps, dropped frames, latency percentiles, time to the first puppet frame)")
    p.set_defaults(func=run)


def _puppet(args) -> str:
    from ..errors import BadInputError

    if args.puppet_pos is not None and args.puppet is not None and args.puppet_pos != args.puppet:
        raise BadInputError(f"two puppets given ({args.puppet_pos} and --puppet {args.puppet}): give one")
    p = args.puppet if args.puppet is not None else args.puppet_pos
    if p is None:
        raise BadInputError("no puppet given: facetex live --puppet PERSON.persona [--source 0] [-o OUT.mp4]")
    return p


def _progress(args):
    if args.quiet:
        return None

    def show(st):
        print(f"\rlive: {st['fps']:5.1f} fps, {st['puppet_frames']} puppet frames, dropped {st['dropped']} "
              f"({st['dropped_pct']:.1f} %), latency p50 {st['latency_ms_p50'] or 0:.0f} ms "
              f"p95 {st['latency_ms_p95'] or 0:.0f} ms   ", end="", file=sys.stderr, flush=True)

    return show


def run(args) -> int:
    import os

    if "numpy" not in sys.modules:  # BLAS on one thread: the live stages run their own threads
        os.environ.update(OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    puppet = _puppet(args)
    if args.workers != "process":
        return _run(args, puppet)
    # the worker processes start (and load their models) beside this one's imports and checks
    from ..live._workers import discard_prestarted, prestart

    prestart("facetex.live._tracking:_make_tracker", name="live tracking")
    prestart("facetex.live._render:_make_renderer", name="live rendering")
    try:
        return _run(args, puppet)
    finally:
        discard_prestarted()  # those no session took (an error before it started)


def _run(args, puppet) -> int:
    from ..errors import BadInputError
    from ..io import VIDEO_EXTENSIONS, check_output_path
    from ..live.runner import display_available
    from ..live.sources import source_kind
    from ..persona import read_persona_header
    from ._common import check_device

    check_device(args.device)  # the live path runs on the CPU (no torch stage); a bad device is still an error
    inputs = [puppet] + ([args.source] if source_kind(args.source) == "file" else [])
    out = sidecar = None
    if args.output is not None:
        out = check_output_path(args.output, overwrite=args.overwrite, inputs=inputs, extensions=VIDEO_EXTENSIONS,
                                what="video")
        sidecar = check_output_path(f"{out}.json", overwrite=args.overwrite, inputs=inputs)
    window = args.window or out is None
    if window and not display_available():
        raise BadInputError("no display to show the live output (DISPLAY is not set, or OpenCV has no GUI): "
                            "give -o OUT.mp4")
    read_persona_header(puppet)  # a missing or wrong persona fails before the source is opened
    from ..live import LiveParams, LiveSession, run_live

    live = LiveParams(lost_output=args.lost, tracking=args.workers, render=args.workers)
    with LiveSession(puppet, size=args.size, mode=args.mode, live=live) as session:
        report = run_live(args.source, session=session, output=out, overwrite=args.overwrite, window=window,
                          max_frames=args.max_frames, duration=args.duration, loop=args.loop,
                          progress=_progress(args))
    if not args.quiet:
        print("", file=sys.stderr)
    if out is not None:
        from .._provenance import provenance
        from ..io import write_json

        write_json(sidecar, provenance(
            command="live", inputs={"puppet": puppet, "source": args.source if "file" == source_kind(args.source)
                                    else None},
            params={"source": str(args.source), "size": args.size, "mode": args.mode, "lost": args.lost,
                    "max_frames": args.max_frames, "duration": args.duration, "loop": args.loop,
                    "workers": args.workers, "device": args.device, "live_params": live},
            seed=args.seed, outputs=[out], result=report), overwrite=args.overwrite, inputs=inputs)
    if args.json:
        print_json(report)
    elif not args.quiet:
        print(f"live: {report['puppet_frames']} puppet frames at {report['fps']:.1f} fps (sustained "
              f"{report['sustained_fps']:.1f}), dropped {report['dropped']} of {report['frames_in']} "
              f"({report['dropped_pct']:.1f} %), latency p50 {report['latency_ms_p50']} ms p95 "
              f"{report['latency_ms_p95']} ms, first puppet frame after {report['first_puppet_s']} s", file=sys.stderr)
        if out is not None:
            print(f"wrote {out}\nwrote {sidecar}")
    return 0
