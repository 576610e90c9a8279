"""Command-line front end: ``facetex COMMAND ...``.

Each sub-command lives in a module ``facetex/cli/cmd_<name>.py`` that defines
``register(subparsers)``; the parser gets ``func`` set to the function that runs it.
The CLI parses, calls the Python API and prints: it holds no algorithm.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import pkgutil
import signal
import sys
import threading
import traceback
import warnings

from ..errors import FacetexError, OutputError, UsageError


class _Parser(argparse.ArgumentParser):
    """argparse whose errors are one ``facetex: error:`` line (exit 2), like every other error."""

    def error(self, message):
        where = self.prog.partition(" ")[2]  # "transfer", "persona texture"; "" for the root parser
        raise UsageError(f"{where + ': ' if where else ''}{message} (see `{self.prog} --help`)")


class Terminated(KeyboardInterrupt):
    """SIGTERM / SIGHUP, raised in the main thread so that they unwind like Ctrl-C: temporary
    files removed, worker processes stopped and reaped."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@contextlib.contextmanager
def _signals_as_interrupts():
    """Handle SIGTERM and SIGHUP like SIGINT while a command runs (main thread only); the
    handlers fire once, a second signal during the clean-up is ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    sigs = [s for s in (signal.SIGTERM, getattr(signal, "SIGHUP", None)) if s is not None]
    old = {s: signal.getsignal(s) for s in sigs}

    def handler(signum, frame):
        for s in sigs:
            signal.signal(s, signal.SIG_IGN)
        raise Terminated(signum)

    for s in sigs:
        signal.signal(s, handler)
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def _command_of(argv) -> str | None:
    """The sub-command named in ``argv`` (the first word that is not an option), or None."""
    return next((a for a in argv if not a.startswith("-")), None) if argv else None


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The CLI parser; with ``command``, only that sub-command's parser when it has its own
    ``cmd_<command>`` module (the others import numpy, PyAV and the benches' modules: ~0.4 s,
    which a ``facetex puppet`` run spends before its driver tracking starts)."""
    from .. import __version__

    parser = _Parser(
        prog="facetex",
        description="Photo-realistic facial texture: FaceTex transfer and Persona textures.",
    )
    parser.add_argument("-V", "--version", action="version", version=f"facetex {__version__}")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    names = sorted(m.name for m in pkgutil.iter_modules(__path__) if m.name.startswith("cmd_"))
    if command is not None and f"cmd_{command}" in names:
        importlib.import_module(f"{__name__}.cmd_{command}").register(sub)
        if command not in sub.choices:  # the module registers other names: the whole parser
            return build_parser()
    else:
        for name in names:
            importlib.import_module(f"{__name__}.{name}").register(sub)
    _accept_debug_anywhere(parser)
    return parser


def iter_commands(parser: argparse.ArgumentParser | None = None, prefix: tuple = ()):
    """(name, parser) of every command of the CLI ("persona build", ...), each parser once (the
    docs' CLI reference and the convention test walk the same tree)."""
    parser = build_parser() if parser is None else parser
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield " ".join(prefix), parser
        return
    for s in subs:
        seen = set()
        for name, p in s.choices.items():
            if id(p) not in seen:
                seen.add(id(p))
                yield from iter_commands(p, prefix + (name,))


def _accept_debug_anywhere(parser: argparse.ArgumentParser) -> None:
    """Let ``--debug`` also follow the sub-command (``facetex landmarks x.jpg --debug``), and give
    every command ``-q/--quiet`` (the convention: no progress bar and no success message)."""
    from ._common import add_quiet

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for p in action.choices.values():
                if "--debug" not in p._option_string_actions:
                    p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
                if not any(isinstance(a, argparse._SubParsersAction) for a in p._actions):
                    if "--quiet" not in p._option_string_actions:
                        add_quiet(p)
                else:
                    _accept_debug_anywhere(p)
                _accept_debug_anywhere(p)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Python warnings as one ``facetex: warning: ...`` line each (no source location)."""
    from tqdm import tqdm  # tqdm.write keeps the line off a running progress bar

    text = " ".join(str(message).split())
    tqdm.write(f"facetex: warning: {text}", file=sys.stderr if file is None else file)


def _passive_openmp() -> None:
    """Let torch's OpenMP threads sleep, not spin, while they wait (unless the user chose):
    on a 2-core machine shared with other jobs the spinning threads starve each other; the
    demo took 232 s instead of 39 s (load average 5, 2 threads, identical output). Must run
    before torch is imported (the parser never imports it)."""
    import os

    if "torch" not in sys.modules:
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


class _Stdout:
    """sys.stdout while a command runs: a write or flush that fails (stdout closed with ``>&-``,
    ``> /dev/full``) is an OutputError, one line, not a traceback. A reader that went away
    (BrokenPipeError) is left to :func:`_stdout_closed`."""

    def __init__(self, stream):
        self._stream = stream
        self.error: OutputError | None = None  # the first failed write (argparse's --version swallows it)

    def _call(self, name, *args):
        if self._stream is None:
            self.error = OutputError("cannot write to stdout: it is closed (give the command an open stdout, "
                                     "e.g. > /dev/null)")
            raise self.error
        try:
            return getattr(self._stream, name)(*args)
        except BrokenPipeError:
            raise
        except OSError as e:
            self.error = self.error or OutputError(f"cannot write to stdout ({e.strerror or e})")
            raise self.error from None

    def write(self, text):
        return self._call("write", text)

    def flush(self):
        if self._stream is not None:
            return self._call("flush")

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _reserve_std_fds() -> None:
    """Put /dev/null on file descriptors 0-2 that are closed (``>&-``): else the next file
    opened (an output) would get that number, and a library printing to stdout would write
    into it."""
    import os

    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            try:
                got = os.open(os.devnull, os.O_RDWR)
            except OSError:
                return
            if got != fd:  # a lower one was closed too: it is reserved in its own turn
                os.dup2(got, fd)
                os.close(got)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    _reserve_std_fds()
    _passive_openmp()
    from .._resources import matplotlib_outside_a_missing_home

    matplotlib_outside_a_missing_home()
    debug = "--debug" in argv
    out = _Stdout(sys.stdout)
    stdout, sys.stdout = sys.stdout, out
    try:
        try:
            with warnings.catch_warnings(), _signals_as_interrupts():
                if not debug:
                    warnings.showwarning = _show_warning
                code = _run(argv, debug)
        except SystemExit as exc:  # --help, --version: argparse ignores a failed write
            if out.error is not None and exc.code in (0, None):
                print(f"facetex: error: {out.error}", file=sys.stderr)
                _stdout_closed()
                raise SystemExit(out.error.exit_code) from None
            raise
        try:
            out.flush()
        except BrokenPipeError:
            return _stdout_closed()
        except OutputError as exc:
            print(f"facetex: error: {exc}", file=sys.stderr)
            _stdout_closed()  # the unwritable buffer is dropped, not flushed again at exit
            return exc.exit_code
        except ValueError:  # closed by the command
            pass
        return code
    finally:
        sys.stdout = stdout


def _one_line(message) -> str:
    """``message`` on one line: control characters (a line break in a file name) escaped."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(message))


def _stdout_closed() -> int:
    """The reader of our stdout went away (``facetex landmarks --json | head``): stop quietly,
    as a command killed by SIGPIPE does (exit 141), and keep Python from complaining about the
    unflushed buffer at exit."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):
        pass
    return 128 + 13


def _interrupted(exc: KeyboardInterrupt) -> int:
    """One line saying what an interrupted command left behind; exit 128 + signal number."""
    from ..io import committed_outputs

    signum = getattr(exc, "signum", signal.SIGINT)
    kept = committed_outputs()
    what = "" if signum == signal.SIGINT else f" by {signal.Signals(signum).name}"
    if kept:
        names = ", ".join(str(p) for p in kept[:3]) + (f" and {len(kept) - 3} more" if len(kept) > 3 else "")
        print(f"facetex: interrupted{what}; the run did not finish; kept {len(kept)} file(s) it had already "
              f"written: {names}", file=sys.stderr)
    else:
        print(f"facetex: interrupted{what}; no partial output was written", file=sys.stderr)
    return 128 + int(signum)


def _run(argv: list[str], debug: bool) -> int:
    from .._provenance import set_command

    io = sys.modules.get(f"{__package__.rpartition('.')[0]}.io")
    if io is not None:  # not imported yet: nothing committed (and numpy/OpenCV not loaded before a
        io.committed_outputs(reset=True)  # puppet run starts its driver tracking: ~0.35 s)
    set_command(argv)
    args = None
    try:
        args = build_parser(_command_of(argv)).parse_args(argv)
        try:
            result = args.func(args)
        finally:
            set_command(None)
        return int(result or 0)
    except FacetexError as exc:
        if debug:
            traceback.print_exc()
        print(f"facetex: error: {_one_line(exc)}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt as exc:
        return _interrupted(exc)
    except BrokenPipeError:
        return _stdout_closed()
    except MemoryError:
        if debug:
            traceback.print_exc()
        hint = "; try a smaller --size" if hasattr(args, "size") else ""
        print(f"facetex: error: out of memory{hint}", file=sys.stderr)
        return 3
    except RecursionError as exc:
        if debug:
            traceback.print_exc()
        print(f"facetex: error: input nested too deeply ({exc})", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - last resort: one line, not a traceback
        if debug:
            traceback.print_exc()
        print(
            f"facetex: internal error: {type(exc).__name__}: {_one_line(exc)} (run with --debug for the traceback)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
