"""Command-line front end: ``facetex COMMAND ...``.

Each sub-command lives in a module ``facetex/cli/cmd_<name>.py`` that defines
``register(subparsers)``; the parser gets ``func`` set to the function that runs it.
The CLI parses, calls the Python API and prints: it holds no algorithm.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
import traceback
import warnings

from ..errors import FacetexError


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = argparse.ArgumentParser(
        prog="facetex",
        description="Photo-realistic facial texture: FaceTex transfer and Persona textures.",
    )
    parser.add_argument("--version", action="version", version=f"facetex {__version__}")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("cmd_"):
            importlib.import_module(f"{__name__}.{info.name}").register(sub)
    _accept_debug_anywhere(parser)
    return parser


def _accept_debug_anywhere(parser: argparse.ArgumentParser) -> None:
    """Let ``--debug`` also follow the sub-command (``facetex landmarks x.jpg --debug``)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for p in action.choices.values():
                p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
                _accept_debug_anywhere(p)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Python warnings as one ``facetex: warning: ...`` line each (no source location)."""
    from tqdm import tqdm  # tqdm.write keeps the line off a running progress bar

    text = " ".join(str(message).split())
    tqdm.write(f"facetex: warning: {text}", file=sys.stderr if file is None else file)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv
    with warnings.catch_warnings():
        if not debug:
            warnings.showwarning = _show_warning
        return _run(argv, debug)


def _run(argv: list[str], debug: bool) -> int:
    try:
        args = build_parser().parse_args(argv)
        result = args.func(args)
        return int(result or 0)
    except FacetexError as exc:
        if debug:
            traceback.print_exc()
        print(f"facetex: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("facetex: interrupted; no partial output was written", file=sys.stderr)
        return 130
    except MemoryError:
        if debug:
            traceback.print_exc()
        print("facetex: error: out of memory; try a smaller --size", file=sys.stderr)
        return 3
    except Exception as exc:  # noqa: BLE001 - last resort: one line, not a traceback
        if debug:
            traceback.print_exc()
        print(
            f"facetex: internal error: {type(exc).__name__}: {exc} (run with --debug for the traceback)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
