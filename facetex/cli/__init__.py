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
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv
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
