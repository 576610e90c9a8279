"""``facetex serve`` — the local web studio (:mod:`facetex.studio`) with uvicorn."""

from __future__ import annotations

import sys

import argparse
import math
import re

from ._common import add_json, add_quiet, bounded_int, finite_float, print_json

LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")
_UNITS = {"": 1, "s": 1, "m": 60, "h": 3600, "d": 86400}


def duration(text: str) -> float:
    """argparse type: seconds, or a number with s, m, h or d (``90m``, ``12h``, ``7d``)."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([smhd]?)\s*", text.lower())
    v = float(m.group(1)) * _UNITS[m.group(2)] if m else math.nan
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a positive duration such as 3600, 90m, 12h or 7d, not {text!r}")
    return v


def register(sub) -> None:
    p = sub.add_parser(
        "serve", help="a local web studio: transfer, persona, puppet and live pages in the browser",
        description="Serve the facetex studio: pages for texture transfer, persona building, puppetry and "
                    "live puppetry from the browser's camera. Jobs run one at a time, each in its own folder "
                    "under --workdir. Needs the studio extra: pip install 'facetex[studio]'.")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1: this machine only; another address lets "
                        "others on the network use the studio and its CPU)")
    p.add_argument("--port", type=bounded_int(0, 65535), default=8000, help="port (default 8000; 0: any free one)")
    p.add_argument("--workdir", metavar="DIR", help="folder of the job folders (default: a new temporary folder)")
    p.add_argument("--max-upload-mb", type=finite_float(0.0, 100_000, open_lo=True), default=200, metavar="MB",
                   help="largest upload (one request, all its files) in MB (default 200)")
    p.add_argument("--workers", type=bounded_int(1, 64), default=1, metavar="N",
                   help="jobs run at once (default 1; the others wait in order)")
    p.add_argument("--max-queued", type=bounded_int(1, 10_000), default=8, metavar="N",
                   help="jobs that may wait (default 8; beyond, a new job is refused until one finishes)")
    p.add_argument("--keep-jobs", type=bounded_int(0, 1_000_000), default=100, metavar="N",
                   help="finished jobs whose folders are kept, the newest (default 100); older ones are removed at "
                        "start-up and then every --cleanup-interval, those an earlier server left in --workdir too")
    p.add_argument("--job-ttl", type=duration, metavar="TIME",
                   help="remove a finished job's folder after this long (seconds, or 90m, 12h, 7d; default: never)")
    p.add_argument("--cleanup-interval", type=duration, default=60.0, metavar="TIME",
                   help="time between two clean-ups of the job folders (default 60 s)")
    p.add_argument("--personas", metavar="DIR",
                   help="a folder of .persona files offered on the Puppet and Live pages")
    p.add_argument("--open", action="store_true", help="open the studio in the web browser")
    add_quiet(p)
    add_json(p, 'the address and work folder ({"url": ..., "workdir": ...}) when the server is up')
    p.set_defaults(func=run)


def run(args) -> int:
    from ..errors import BadInputError

    try:
        import uvicorn

        from ..studio import create_app
    except ImportError as e:
        raise BadInputError(f"the studio needs {e.name}: pip install 'facetex[studio]'") from None
    import tempfile
    from pathlib import Path

    if args.workdir:
        workdir = Path(args.workdir)
        if workdir.exists() and not workdir.is_dir():
            raise BadInputError("not a folder", path=workdir)
    else:
        workdir = Path(tempfile.mkdtemp(prefix="facetex-studio-"))
    if args.host not in LOCAL_HOSTS:
        import warnings

        warnings.warn(f"--host {args.host}: the studio is reachable from other machines; it has no login, and "
                      "anyone who reaches it can run jobs on this machine and download their results")
    app = create_app(workdir, max_upload_mb=args.max_upload_mb, workers=args.workers,
                     max_queued=args.max_queued, personas_dir=args.personas, keep_jobs=args.keep_jobs,
                     job_ttl=args.job_ttl, cleanup_interval=args.cleanup_interval)
    # no per-message deflate: the Live page's messages are JPEGs, which it would only spend CPU on
    config = uvicorn.Config(app, host=args.host, port=args.port, log_level="warning", ws_max_size=8 * 2**20,
                            ws_per_message_deflate=False)
    server = uvicorn.Server(config)

    def started():
        sock = server.servers[0].sockets[0].getsockname()
        host = f"[{sock[0]}]" if ":" in sock[0] else sock[0]
        url = f"http://{host}:{sock[1]}/"
        if args.json:
            print_json({"url": url, "workdir": str(workdir.resolve())})
        elif not args.quiet:
            print(f"facetex studio at {url} (jobs in {workdir}); Ctrl-C stops it")
        sys.stdout.flush()
        if args.open:
            import webbrowser

            webbrowser.open(url)

    # uvicorn says when it listens through its startup: the URL (with the port chosen for --port 0)
    # is printed then, not before
    original = server.startup

    async def startup(sockets=None):
        await original(sockets=sockets)
        if server.started:
            started()

    server.startup = startup
    try:
        server.run()
    except SystemExit:  # uvicorn's way out of a failed bind (it has logged the OS's reason)
        pass
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM, re-raised by uvicorn once it has shut down: the way to stop
        if server.started:
            if not (args.quiet or args.json):
                print("facetex studio stopped")
            return 0
        raise
    if not server.started:
        raise BadInputError(f"cannot listen on {args.host}:{args.port} (in use, or not an address of this machine)")
    return 0
