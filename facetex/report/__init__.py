"""Reports of run folders: ``facetex report`` (one self-contained HTML page) and ``facetex compare``.

- :func:`load_run` reads a folder written by ``facetex bench ...``, ``facetex demo`` or single
  runs with sidecars;
- :func:`build_report` makes the HTML page, :func:`write_report` writes it with its sidecar;
- :func:`compare_table` is the side-by-side metrics table of several runs;
- :mod:`.figures`: :func:`zoom_panel` (face crops at native resolution) and
  :func:`metrics_figure` (per-item metrics, mean and 95 % CI, paper reference marks).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from .compare import compare_rows, compare_table, metric_summary
from .figures import face_box, metrics_figure, skin_box, zoom_panel
from .html import build_report
from .runs import Item, ReadGuard, Run, load_run, load_runs

__all__ = ["Run", "Item", "load_run", "load_runs", "ReadGuard", "build_report", "write_report", "compare_rows",
           "compare_table", "metric_summary", "zoom_panel", "metrics_figure", "face_box", "skin_box"]


def write_report(run_dirs: Sequence, output, *, title: str | None = None, overwrite: bool = False,
                 also: Sequence = ()) -> Path:
    """Read ``run_dirs``, write the report page ``output`` (.html) and ``output.json`` (its
    provenance: the run folders and their run.json hashes), both or neither. Only regular
    files inside ``run_dirs`` and ``also`` (e.g. a bench's data folder, for its content and
    style images) are read; the others are skipped, with a warning (see :func:`load_runs`).

    Examples
    --------
    >>> from facetex.report import write_report
    >>> write_report(["bench_out/transfer"], "report.html")  # doctest: +SKIP
    """
    from .._provenance import provenance
    from ..io import check_output_path, encode_json, write_files

    out = check_output_path(output, overwrite=overwrite, extensions=(".html", ".htm"), what="report")
    sidecar = check_output_path(f"{out}.json", overwrite=overwrite)
    runs = load_runs(run_dirs, also=also)
    page = build_report(runs, title=title, link_base=out.parent)
    inputs = {}
    for i, r in enumerate(runs):
        inputs[f"run{i + 1}"] = r.path / "run.json" if r.provenance is not None else r.path
    record = provenance(command="report", inputs=inputs, params={"title": title, "runs": [str(r.path) for r in runs]},
                        outputs=[out], kinds=[r.kind for r in runs], bytes=len(page.encode("utf-8")))
    write_files({out: page.encode("utf-8"), sidecar: encode_json(record)}, overwrite=overwrite)
    return out
