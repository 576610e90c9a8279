"""Shared CLI pieces: common options and their checks, JSON printing, progress bars.

The checks here run at the start of a command, before any computation: a run that is
going to fail fails in the first second, not after the work."""

from __future__ import annotations

import argparse
import json
import math
import sys
from contextlib import contextmanager

from tqdm import tqdm

from .._args import DEVICE_PATTERN, SEED_MAX


def bounded_int(lo: int | None = None, hi: int | None = None, what: str = "an integer"):
    """argparse type: an integer in [lo, hi] (either bound may be None)."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, not {text!r}") from None
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            rng = (f"from {lo} to {hi}" if lo is not None and hi is not None
                   else f"at least {lo}" if lo is not None else f"at most {hi}")
            raise argparse.ArgumentTypeError(f"must be {rng}, not {v}")
        return v

    parse.__name__ = "integer"
    return parse


positive_int = bounded_int(1)
nonnegative_int = bounded_int(0)


def finite_float(lo: float | None = None, hi: float | None = None, *, open_lo: bool = False):
    """argparse type: a finite float in [lo, hi] (``open_lo``: strictly above lo)."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, not {text!r}") from None
        if not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"must be a finite number, not {text!r}")
        if lo is not None and (v < lo or (open_lo and v == lo)):
            raise argparse.ArgumentTypeError(f"must be {'above' if open_lo else 'at least'} {lo:g}, not {text}")
        if hi is not None and v > hi:
            raise argparse.ArgumentTypeError(f"must be at most {hi:g}, not {text}")
        return v

    parse.__name__ = "number"
    return parse


def device_name(text: str) -> str:
    """argparse type of ``--device``: the syntax only (availability: :func:`check_device`)."""
    t = text.strip().lower()
    if not DEVICE_PATTERN.match(t):
        raise argparse.ArgumentTypeError(f"unknown device {text!r}: use cpu or cuda (cuda:N for a given GPU)")
    return t


def check_device(device: str) -> str:
    """Raise BadInputError unless torch can run on ``device`` here (called at the start of a
    command that computes with torch, before reading any input)."""
    from .._args import check_device as check

    return check(device, what="--device")


def add_seed_device(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seed", type=bounded_int(0, SEED_MAX), default=0, metavar="N",
                        help="random seed, 0 to 2**63 - 1 (default 0)")
    parser.add_argument("--device", type=device_name, default="cpu", metavar="{cpu,cuda,cuda:N,mps}",
                        help="torch device (default cpu; cuda needs a CUDA build of torch)")


def add_overwrite(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--overwrite", action="store_true", help="replace existing outputs")


def add_quiet(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar and no success message (errors are still printed)")


def add_json(parser: argparse.ArgumentParser, what: str = "the result") -> None:
    parser.add_argument("--json", action="store_true", help=f"print {what} as JSON on stdout (nothing else)")


def add_output(parser: argparse.ArgumentParser, *, dest: str = "output", **kwargs) -> None:
    """The output option of every command: ``-o/--output``, with ``--out`` (the bench, batch and
    demo commands' older spelling) as an alias."""
    parser.add_argument("-o", "--output", "--out", dest=dest, **kwargs)


def add_jobs(parser, what: str = "worker processes") -> None:
    """``--jobs N``: the one default of every command, the CPUs this process may use."""
    parser.add_argument("--jobs", type=bounded_int(1, 4096), default=None, metavar="N",
                        help=f"{what} (default: the available CPUs)")


def jobs_of(args) -> int:
    """``--jobs`` with its default (the available CPUs) resolved."""
    from .._parallel import available_cpus

    return int(args.jobs) if getattr(args, "jobs", None) else available_cpus()




def say(args, *lines: str) -> None:
    """Success lines (``wrote PATH``) on stdout, unless ``--quiet`` or ``--json``."""
    if getattr(args, "quiet", False) or getattr(args, "json", False):
        return
    for line in lines:
        print(line)


def wrote(args, *paths, **summary) -> None:
    """``wrote PATH`` for each written file (see :func:`say`); with ``--json``
    ``{"outputs": [...], **summary}`` instead (commands with a JSON of their own print that and
    do not call this)."""
    if getattr(args, "json", False):
        print_json({"outputs": [str(p) for p in paths], **summary})
        return
    say(args, *(f"wrote {p}" for p in paths))


def print_json(obj) -> None:
    json.dump(obj, sys.stdout, indent=2, default=str)
    sys.stdout.write("\n")


def read_json_file(path, error=None, *, what: str = "JSON file"):
    """The parsed JSON of a small input file; one-line errors naming it (missing, FIFO,
    not UTF-8, not JSON, nested too deeply, larger than 64 MB)."""
    from ..errors import BadInputError
    from ..io import check_input_file

    error = error or BadInputError
    p = check_input_file(path, error, what=what)
    if p.stat().st_size > 64 * 2**20:
        raise error(f"{what} larger than 64 MB: give a small JSON file", path=p)
    try:
        text = p.read_text(encoding="utf-8")
        return json.loads(text)
    except UnicodeDecodeError:
        raise error(f"not a UTF-8 text file: give a {what}", path=p) from None
    except RecursionError:
        raise error(f"unreadable {what}: nested too deeply", path=p) from None
    except ValueError as e:
        raise error(f"unreadable {what} ({e})", path=p) from None
    except OSError as e:
        raise error(f"cannot read it ({e.strerror})", path=p) from None


@contextmanager
def progress_bar(total: int | None = None, desc: str = "", unit: str = "it", *, disable: bool = False,
                 leave: bool = True):
    """A tqdm bar on stderr (it stays on screen when done, with its count and time); yields a
    callback ``update(n=1, **postfix)`` for the API. ``disable``: no bar (``--quiet``)."""
    bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, dynamic_ncols=True, leave=leave,
               disable=disable)

    def update(n: int = 1, **postfix):
        if postfix:
            bar.set_postfix(postfix, refresh=False)
        if bar.total is not None and bar.n + n > bar.total:  # an estimated total: grow it, never overflow
            bar.total = bar.n + n
        bar.update(n)

    try:
        yield update
        if bar.total is not None and bar.n < bar.total:  # an estimated total: end the finished bar at 100 %
            bar.total = bar.n
            bar.refresh()
    finally:
        bar.close()


def add_engine_options(parser: argparse.ArgumentParser, *, jobs: bool = True, jobs_default: int | None = None,
                       jobs_help: str | None = None, cpus_help: str | None = None) -> None:
    """``--engine local|ray``, ``--jobs N``, ``--address``, ``--cpus-per-item``: where the items of
    a batch or a benchmark run (see :mod:`facetex.batch.engines`)."""
    g = parser.add_argument_group("engine (where the items run)")
    g.add_argument("--engine", choices=("local", "ray"), default="local",
                   help="local (default): worker processes on this machine; ray: tasks on a Ray cluster "
                        "(pip install 'facetex[ray]')")
    if jobs:
        g.add_argument("--jobs", type=bounded_int(1, 4096), default=jobs_default, metavar="N",
                       help=jobs_help or "local: worker processes (default: the available CPUs); ray: items in "
                                         "flight at once (default: the cluster's CPUs / --cpus-per-item)")
    g.add_argument("--address", metavar="ADDR",
                   help="--engine ray: the cluster, auto | HOST:PORT | ray://HOST:PORT (default: start a local Ray "
                        "on this machine, stopped at the end)")
    g.add_argument("--runtime-env", type=runtime_env, metavar="JSON|FILE",
                   help="--engine ray: Ray's runtime environment of the job, a JSON object or a .json file "
                        "(e.g. '{\"pip\": [\"facetex[s3]\"], \"env_vars\": {...}}'), so nodes need no manual install")
    g.add_argument("--cpus-per-item", type=bounded_int(1, 1024), metavar="N",
                   help=cpus_help or "CPUs (torch threads) of one item (default: local, the CPUs / --jobs; ray, 1)")


def runtime_env(text: str) -> dict:
    """argparse type of ``--runtime-env``: a JSON object, or the path of a file holding one."""
    import os

    src = text
    if not text.lstrip().startswith("{"):
        if not os.path.isfile(text):
            raise argparse.ArgumentTypeError(f"give a JSON object or a .json file, not {text!r}")
        try:
            with open(text, encoding="utf-8") as fh:
                src = fh.read()
        except (OSError, UnicodeDecodeError) as e:
            raise argparse.ArgumentTypeError(f"cannot read {text}: {e}") from None
    try:
        value = json.loads(src)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"not JSON ({e})") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError("must be a JSON object (working_dir, pip, env_vars, ...)")
    return value


runtime_env.__name__ = "runtime environment"


def engine_from_args(args, *, inline_single: bool = False):
    """The engine the ``--engine`` options ask for (not started)."""
    from ..batch.engines import make_engine
    from ..errors import BadInputError

    if args.address and args.engine != "ray":
        raise BadInputError("--address needs --engine ray")
    return make_engine(args.engine, jobs=getattr(args, "jobs", None), address=args.address,
                       cpus_per_item=args.cpus_per_item, device=getattr(args, "device", "cpu"),
                       inline_single=inline_single, runtime_env=getattr(args, "runtime_env", None))
