"""``facetex report RUN_DIR ... -o report.html`` and ``facetex compare RUN_DIR RUN_DIR`` — look at runs."""

from __future__ import annotations

from ._common import add_json, add_output, add_overwrite, add_quiet, print_json, wrote


def register(sub) -> None:
    p = sub.add_parser(
        "report", help="one self-contained HTML page of run folders (tables, figures, zoomable images)",
        description="Read run folders written by `facetex bench ...`, `facetex demo` or single runs with "
                    "sidecars, and write one HTML file with everything inside: settings, tables with "
                    "spread, figures with the paper's values as reference marks, image grids (click to "
                    "compare at 100 %), zoom panels, per-item metrics, provenance, and with two or more "
                    "folders a side-by-side comparison.")
    p.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run folder(s)")
    add_output(p, required=True, metavar="REPORT.html", help="HTML file to write (+ .json sidecar)")
    p.add_argument("--title", help="page title (default: the folders' names)")
    p.add_argument("--data", action="append", default=[], metavar="DIR",
                   help="also show the content and style images inside DIR (a bench's --data folder); files "
                        "outside the run folders and these are skipped (repeatable)")
    add_overwrite(p)
    add_quiet(p)
    add_json(p, "the written files")
    p.set_defaults(func=run_report)

    c = sub.add_parser("compare", help="metrics of run folders side by side (mean ± std per method and metric)",
                       description="Print the metrics of two or more run folders side by side: per method and "
                                   "metric, each run's mean ± sample std over its items, and the difference "
                                   "of the means from the first run (the report's comparison as a table).")
    c.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run folders (two or more)")
    c.add_argument("--markdown", action="store_true", help="print a Markdown table")
    add_json(c, "the rows")
    c.set_defaults(func=run_compare)


def run_report(args) -> int:
    from ..errors import BadInputError
    from ..io import check_input_dir
    from ..report import write_report

    for d in args.data:
        check_input_dir(d, BadInputError, what="--data folder")
    out = write_report(args.runs, args.output, title=args.title, overwrite=args.overwrite, also=args.data)
    wrote(args, out, f"{out}.json")
    return 0


def run_compare(args) -> int:
    from ..errors import BadInputError
    from ..report import compare_rows, compare_table, load_runs

    if len(args.runs) < 2:
        raise BadInputError("compare needs two or more run folders (see `facetex report` for one)")
    runs = load_runs(args.runs, images=False)  # a table of metrics: no image is read
    if args.json:
        print_json({"runs": [{"path": str(r.path), "kind": r.kind, "items": len(r.items)} for r in runs],
                    "rows": compare_rows(runs)})
    else:
        print(compare_table(runs, markdown=args.markdown), end="")
    return 0
