"""``facetex samples DIR`` — copy the bundled sample portraits (CC BY 4.0) to try the commands on."""

from __future__ import annotations

from ._common import add_json, add_overwrite, add_quiet, wrote


def register(sub) -> None:
    p = sub.add_parser("samples", help="copy the bundled sample portraits (FRL London, CC BY 4.0) into a folder",
                       description="Copy the six bundled 400 px portraits (Face Research Lab London Set, "
                                   "DeBruine & Jones 2017, CC BY 4.0) and their attribution into DIR, to try "
                                   "every command on. Existing files are kept unless --overwrite.")
    p.add_argument("folder", metavar="DIR", help="folder to create (or an existing one)")
    add_overwrite(p)
    add_quiet(p)
    add_json(p, "the written files")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from .._resources import sample_path
    from ..errors import OutputError
    from ..io import check_output_path, write_files

    out = Path(args.folder)
    if out.exists() and not out.is_dir():
        raise OutputError("exists and is not a folder: give a folder name", path=out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"cannot create the folder ({e.strerror})", path=out) from None
    files = {out / p.name: p.read_bytes() for p in sorted(sample_path().iterdir())
             if p.suffix.lower() in (".jpg", ".md")}
    for p in files:
        check_output_path(p, overwrite=args.overwrite)
    write_files(files, overwrite=args.overwrite)
    wrote(args, *files)
    return 0
