"""``facetex batch transfer|persona|puppet`` — many items, resumable, on this machine or a Ray cluster."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ._common import (add_engine_options, add_json, add_output, add_overwrite, add_quiet, add_seed_device, bounded_int, check_device,
                      finite_float, positive_int, print_json, say)

EXIT_INCOMPLETE = 4  # the batch ended with failed (or unfinished) items


def _pairs(text: str):
    if text.strip().lower() == "all":
        return "all"
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'all' or a number of pairs, not {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"must be 'all' or at least 1, not {n}")
    return n


_pairs.__name__ = "pairs"


def _batch_options(p: argparse.ArgumentParser) -> None:
    add_output(p, dest="out", required=True, metavar="DIR",
                   help="output folder (created); gets the outputs with their sidecars and manifest.jsonl")
    add_engine_options(p, cpus_help="CPUs (torch threads) of one item (default 1 on every engine, whatever --jobs: "
                                    "outputs are the same bytes for the same seeds and threads; the sidecar records "
                                    "them)")
    g = p.add_argument_group("resuming and faults")
    g.add_argument("--retry-failed", action="store_true",
                   help="run again the items a previous run recorded as failed (default: leave them failed)")
    g.add_argument("--max-retries", type=bounded_int(0, 100), default=2, metavar="N",
                   help="run an item again up to N times when its worker dies (killed, out of memory; default 2)")
    g.add_argument("--claim-timeout", type=finite_float(5.0), default=300.0, metavar="S",
                   help="a claim on an item not refreshed for S seconds is taken over (its run died; default 300). "
                        "Runs on several hosts sharing --out need clocks that agree to well within S")
    add_json(p, "the run's summary")
    add_quiet(p)


def register(sub) -> None:
    from ..transfer.methods import METHODS, PRESETS
    from .cmd_transfer import _iters

    p = sub.add_parser("batch", help="run many transfers, persona builds or puppet renders (resumable; local or Ray)",
                       description="Run many items of one kind, each written with its sidecar, resumably: finished "
                                   "items are skipped, failed ones recorded (and retried with --retry-failed), and "
                                   "several runs may share one output folder (on one host or several). "
                                   "DIR/manifest.jsonl lists every item, its state, host, time and error. Exit "
                                   f"code {EXIT_INCOMPLETE} when items failed.")
    bs = p.add_subparsers(dest="batch_command", metavar="KIND")
    bs.required = True

    t = bs.add_parser("transfer", help="texture transfers of many (content, style) pairs",
                      description="FaceTex (or a baseline) on many pairs: from PAIRS.csv (columns content,style and "
                                  "optionally method,preset,seed; paths relative to the CSV's folder) or every "
                                  "image of --contents with every image of --styles. Writes "
                                  "DIR/<content>__<style>__<method>.png and its .png.json.")
    t.add_argument("pairs_csv", nargs="?", metavar="PAIRS.csv", help="CSV of pairs (or use --contents/--styles)")
    t.add_argument("--contents", metavar="DIR", help="folder of content images")
    t.add_argument("--styles", metavar="DIR", help="folder of style images")
    t.add_argument("--pairs", type=_pairs, default="all", metavar="all|N",
                   help="with --contents/--styles: every pair (default) or N of them (ranked by a hash of the names)")
    t.add_argument("--method", choices=METHODS, default="facetex", help="method of rows without one (default facetex)")
    t.add_argument("--preset", choices=PRESETS, default="default", help="preset of rows without one (default default)")
    t.add_argument("--size", type=bounded_int(32, 4096), metavar="PX", help="working size in px (default: the preset's)")
    t.add_argument("--iters", type=_iters, metavar="N,N,N", help="L-BFGS iterations per level (default: the preset's)")
    add_seed_device(t)
    _batch_options(t)
    t.set_defaults(func=run_transfer)

    q = bs.add_parser("persona", help="one persona per subfolder of photos",
                      description="Build a persona from every subfolder of PEOPLE_DIR (one person each): "
                                  "DIR/<name>.persona and its .persona.json.")
    q.add_argument("people_dir", metavar="PEOPLE_DIR", help="folder with one subfolder of photos per person")
    q.add_argument("--min-photos", type=bounded_int(3), default=10, metavar="N",
                   help="fewest usable photos accepted (default 10)")
    q.add_argument("--allow-mixed", action="store_true", help="build even when a folder shows several people")
    _batch_options(q)
    q.set_defaults(func=run_persona, device="cpu")

    u = bs.add_parser("puppet", help="every driver video with every persona",
                      description="Puppeteer every persona of --puppets with every video of --drivers: "
                                  "DIR/<driver>__<persona>.mp4 and its .mp4.json.")
    u.add_argument("--drivers", required=True, metavar="DIR", help="folder of driver videos")
    u.add_argument("--puppets", required=True, metavar="DIR", help="folder of .persona files")
    u.add_argument("--size", type=bounded_int(32, 4096), metavar="PX", help="longer side of a panel (default: the driver's)")
    u.add_argument("--mode", choices=("composite", "face"), default="composite", help="as in `facetex puppet`")
    u.add_argument("--side-by-side", action="store_true", help="driver frame left of the puppet")
    u.add_argument("--lighting", choices=("stats", "sh", "none"), default="stats", help="as in `facetex puppet`")
    u.add_argument("--texture", choices=("ours", "static"), default="ours", help="as in `facetex puppet`")
    u.add_argument("--weights", choices=("regional", "global"), default="regional",
                   help="expression weights of the texture, as in `facetex puppet` (default regional)")
    u.add_argument("--max-frames", type=positive_int, metavar="N", help="use only the first N frames")
    _batch_options(u)
    u.set_defaults(func=run_puppet, device="cpu")

    st = bs.add_parser("status", help="what a batch folder holds: counts, throughput, failures, slowest items",
                       description="Read a batch folder (a path or a URL such as s3://bucket/aug) without changing "
                                   "it: items per state (pending, running, done, failed), items per hour, the "
                                   "failures grouped by error (file names and numbers masked) and the slowest items.")
    st.add_argument("folder", metavar="DIR", help="the --out of a `facetex batch` run (path or URL)")
    st.add_argument("--slowest", type=bounded_int(0, 1000), default=10, metavar="N",
                    help="list the N slowest finished items (default 10)")
    st.add_argument("--check-inputs", action="store_true",
                    help="also hash the done items' inputs and count those changed since (a rerun redoes them)")
    add_output(st, metavar="FILE.json", help="also write the status as JSON to FILE.json")
    add_overwrite(st)
    add_json(st, "the status")
    add_quiet(st)
    st.set_defaults(func=run_status)


def _argv() -> list[str]:
    import shlex

    from .._provenance import command_line

    return shlex.split(command_line())


def _check_out(args, inputs=()):
    """--out, checked without creating it (that happens once the engine has started); a URL
    (``s3://bucket/folder``) as it is."""
    from ..batch._store import is_url
    from ..errors import OutputError

    if is_url(args.out):
        if any(d and str(d).rstrip("/") == str(args.out).rstrip("/") for d in inputs):
            raise OutputError("--out is an input folder: write the outputs to another folder", path=args.out)
        return str(args.out).rstrip("/")
    out = Path(args.out)
    for d in inputs:
        if d and out.resolve() == Path(d).resolve():
            raise OutputError(f"--out is the input folder {d}: write the outputs to another folder", path=out)
    if out.exists() and not out.is_dir():
        raise OutputError("output path exists and is not a folder: choose another --out", path=out)
    return out


def _run(args, kind: str, items, inputs=()) -> int:
    """Start the engine, then make the output folder (an engine that cannot start, e.g. Ray
    unreachable, leaves nothing behind) and run the items."""
    import signal

    from tqdm import tqdm

    from ..batch import folder_settings, run_batch
    from ..bench._common import check_out_dir

    out = _check_out(args, inputs)
    engine = _engine(args)
    bar = None

    def progress(done, failed, remaining, running, waiting, done_elsewhere):
        nonlocal bar
        if args.quiet:
            return
        if bar is None:
            if not remaining:  # all done already (a resume): no empty bar
                return
            bar = tqdm(total=remaining, desc=f"batch {kind}", unit="item", file=sys.stderr, dynamic_ncols=True)
        post = {"done": done, "failed": failed, "left": remaining}
        if waiting or done_elsewhere:
            post["elsewhere"] = f"{done_elsewhere} done, {waiting} running"
        bar.set_postfix(post, refresh=False)
        n = done + failed + done_elsewhere
        if n > bar.n:
            bar.update(n - bar.n)
        elif sys.stderr.isatty():  # the elapsed time moves on a terminal; a log gets only the changes
            bar.refresh()

    from ..batch._store import is_url, join, name_of

    try:
        with engine:
            if not is_url(out):
                out = check_out_dir(out)
            summary = run_batch(items, out, engine, retry_failed=args.retry_failed, max_retries=args.max_retries,
                                claim_timeout=args.claim_timeout, progress=progress, settings=folder_settings(items),
                                record={"command": f"batch {kind}", "command_line": " ".join(_argv()),
                                        "engine": engine.describe()})
    except KeyboardInterrupt as exc:
        if bar is not None:
            bar.close()
        signum = getattr(exc, "signum", signal.SIGINT)
        how = "" if signum == signal.SIGINT else f" by {signal.Signals(signum).name}"
        print(f"facetex: interrupted{how}; finished items are kept (with their sidecars), running items were "
              f"stopped without partial output; {join(out, 'manifest.jsonl')} lists them; run the same command "
              "to resume", file=sys.stderr)
        return 128 + int(signum)
    finally:
        if bar is not None:
            bar.close()
    s = summary
    rate = f", {60.0 * s.done / s.seconds:.2f} items/min" if s.seconds > 0 and s.done else ""
    elsewhere = f"{s.failed_elsewhere} failed in another run, " if s.failed_elsewhere else ""
    changed = f" ({s.inputs_changed} because an input changed)" if s.inputs_changed else ""
    line = (f"batch {kind}: {s.total} items in {out}: {s.done} computed{changed}, {s.skipped_done} already done, "
            f"{s.done_elsewhere} by another run, {s.failed + s.skipped_failed} failed, {elsewhere}"
            f"{s.remaining} remaining ({s.seconds:.1f} s{rate}; {engine.name} engine)")
    if args.json:
        print_json(s.as_dict())
    else:
        say(args, line)
        computed = set(s.computed)
        written = [join(out, name_of(p)) for it in items if it.key in computed for p in it.outputs]
        if len(written) <= 40:
            say(args, *(f"wrote {p}" for p in written))
        else:
            say(args, f"wrote {len(written)} files in {out} (listed in manifest.jsonl)")
        say(args, f"wrote {s.manifest}")
    for key, err in s.failures[:10]:
        print(f"facetex: {kind} item {key} failed: {err}", file=sys.stderr)
    for key, run, err in s.failures_elsewhere[:10]:
        print(f"facetex: {kind} item {key} failed in another run ({run}): {err}", file=sys.stderr)
    if len(s.failures) > 10:
        print(f"facetex: ... and {len(s.failures) - 10} more failed items (see {s.manifest})", file=sys.stderr)
    if s.skipped_failed and not args.retry_failed:
        print(f"facetex: {s.skipped_failed} item(s) had failed before: pass --retry-failed to run them again",
              file=sys.stderr)
    return 0 if s.ok else EXIT_INCOMPLETE


def _engine(args):
    from ._common import engine_from_args

    # one thread per item unless asked: torch's float sums depend on the thread count, so a
    # default of CPUs / --jobs made --jobs 1 and --jobs 2 give other bytes (README)
    args.cpus_per_item = args.cpus_per_item or 1
    return engine_from_args(args)


def run_transfer(args) -> int:
    from ..batch import pairs_from_folders, read_pairs_csv, transfer_items
    from ..errors import BadInputError

    if args.pairs_csv and (args.contents or args.styles):
        raise BadInputError("give PAIRS.csv or --contents/--styles, not both")
    if not args.pairs_csv and not (args.contents and args.styles):
        raise BadInputError("give PAIRS.csv, or both --contents DIR and --styles DIR")
    if args.pairs_csv:
        rows = read_pairs_csv(args.pairs_csv)
    else:
        rows = pairs_from_folders(args.contents, args.styles, args.pairs, seed=args.seed)
    if args.engine == "local":  # on a Ray cluster the GPUs are the nodes', not necessarily this machine's
        check_device(args.device)
    _engine(args)  # option errors before any output folder is made
    items = transfer_items(rows, args.out, method=args.method, preset=args.preset, seed=args.seed, size=args.size,
                           iters=args.iters, device=args.device, cpus=args.cpus_per_item, argv=_argv())
    return _run(args, "transfer", items, [args.contents, args.styles])


def run_persona(args) -> int:
    from ..batch import persona_items

    _engine(args)
    items, ignored = persona_items(args.people_dir, args.out, min_photos=args.min_photos,
                                   allow_mixed=args.allow_mixed, cpus=args.cpus_per_item, argv=_argv())
    if ignored and not args.quiet:
        print(f"facetex: left out {len(ignored)} subfolder(s) without photos: {', '.join(ignored[:5])}",
              file=sys.stderr)
    return _run(args, "persona", items, [args.people_dir])


def run_puppet(args) -> int:
    from ..batch import puppet_items

    _engine(args)
    items = puppet_items(args.drivers, args.puppets, args.out, size=args.size, mode=args.mode,
                         side_by_side=args.side_by_side, lighting=args.lighting, texture=args.texture,
                         weights=args.weights, max_frames=args.max_frames, cpus=args.cpus_per_item, argv=_argv())
    return _run(args, "puppet", items, [args.drivers, args.puppets])


def run_status(args) -> int:
    from ..batch._status import batch_status

    if args.output:
        from ..io import check_output_path

        check_output_path(args.output, overwrite=args.overwrite, extensions=(".json",))
    s = batch_status(args.folder, slowest=args.slowest, check_inputs=args.check_inputs)
    if args.output:
        from ..io import write_json

        write_json(args.output, s, overwrite=args.overwrite)
    if args.json:
        print_json(s)
        return 0
    c, t = s["counts"], s["throughput"]
    rate = f"{t['items_per_hour']:.1f} items/hour" if t["items_per_hour"] else "no throughput yet"
    lines = [f"{s['folder']}: {s['total']} items: {c['done']} done, {c['failed']} failed, {c['running']} running, "
             f"{c['pending']} pending; {rate}"]
    for r in s["runs"]:
        per = f", {r['items_per_hour']:.1f} items/hour" if r["items_per_hour"] else ""
        lines.append(f"  run {r['run']} ({r['host']}): {r['done']} done, {r['failed']} failed in "
                     f"{(r['seconds'] or 0):.0f} s{per}")
    if s["failures"]:
        lines.append("failures by error:")
        for g in s["failures"]:
            more = ", ..." if g["count"] > len(g["items"]) else ""
            lines.append(f"  {g['count']} × {g['error']} ({', '.join(g['items'])}{more})")
    changed = s["inputs_changed"]
    if changed is not None:
        more = ", ..." if changed["count"] > len(changed["items"]) else ""
        names = f" ({', '.join(changed['items'])}{more})" if changed["items"] else ""
        lines.append(f"inputs changed since: {changed['count']} of {changed['checked']} done items checked{names}; "
                     "a rerun computes them again")
    if s["slowest"]:
        lines.append("slowest items:")
        lines.extend(f"  {r['seconds']:.1f} s  {r['item']}  ({r['host']})" for r in s["slowest"])
    if args.output:
        lines.append(f"wrote {args.output}")
    say(args, *lines)
    return 0
