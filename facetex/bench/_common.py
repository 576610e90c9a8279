"""Shared pieces of the ``facetex bench`` harnesses: portrait folders, pair selection,
a resumable per-item result store, and table / image-grid / text writers.

Everything here is generic: no method names, no metric names. Outputs go through
atomic writes, so an interrupted benchmark never leaves a half-written file.
"""

from __future__ import annotations

import csv
import io
import json
import math
import platform
import re
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence

import cv2
import numpy as np

from ..errors import BadInputError, OutputError
from ..io import atomic_path, to_uint8, write_image, write_json
from .._stats import spread, spread_text  # below both the benches and the report (re-exported)

__all__ = [
    "list_portraits", "select_pairs", "ResultStore", "Column", "markdown_table", "csv_table",
    "write_text", "write_figure", "write_figure_formats", "image_grid", "write_grid", "mean_finite", "json_safe",
    "versions", "check_out_dir", "DATA_ENV", "data_root", "data_folder", "default_out", "add_bench_options",
    "finish_bench", "spread", "spread_text", "non_default_settings", "no_image_data", "pair_rank",
]

#: environment variable naming the data root of the benchmarks (``--data`` overrides it)
DATA_ENV = "FACETEX_DATA"

_IMAGE_EXTS = (".jpg", ".jpeg", ".png")


# ------------------------------------------------------------------------ inputs
def list_portraits(folder, *, tag: str = "neutral") -> dict[str, Path]:
    """``{person id: path}`` of the ``<id>_<tag>.jpg|jpeg|png`` files in ``folder``, sorted by id.

    Raises BadInputError naming ``folder`` when it is missing or not a folder."""
    folder = Path(folder)
    if not folder.is_dir():
        raise BadInputError("data folder not found: give a folder of <id>_neutral.jpg portraits",
                            path=folder)
    pattern = re.compile(rf"^(?P<id>.+)_{re.escape(tag)}$", re.IGNORECASE)
    found = {}
    for p in sorted(folder.iterdir()):
        m = pattern.match(p.stem)
        if m and p.suffix.lower() in _IMAGE_EXTS and p.is_file():
            found.setdefault(m["id"], p)
    return dict(sorted(found.items()))


def pair_rank(a: str, b: str, seed: int = 0) -> str:
    """Sort key of the ordered pair (a, b): a hash of the two ids and the seed, so a pair's
    place does not depend on which other people are in the data folder."""
    import hashlib

    return hashlib.sha256(f"{int(seed)}\0{a}\0{b}".encode("utf-8")).hexdigest()


def select_pairs(ids: Sequence[str], n: int, *, seed: int = 0) -> list[tuple[str, str]]:
    """``n`` ordered (content, style) pairs of *different* ids, deterministic per ``seed``.

    All ordered pairs are ranked by :func:`pair_rank` (a hash of the two ids and the seed);
    going down that ranking, a pair is taken while neither person is in an earlier pair
    (each person in at most one pair while that is possible), then the remaining pairs follow
    in ranking order. Adding a portrait to the folder adds its pairs at their hashed places
    and leaves the others' order alone, so most of the chosen pairs stay (not a reshuffle).
    The first k pairs do not depend on ``n``, so a longer run extends a shorter one. Fewer
    than ``n`` pairs are returned when fewer exist (m people give m(m-1))."""
    ids = sorted(set(ids))
    if len(ids) < 2:
        raise BadInputError(f"need at least 2 different people to pair, got {len(ids)}")
    if n < 1:
        raise BadInputError(f"number of pairs must be at least 1, got {n}")
    ranked = sorted(((a, b) for a in ids for b in ids if a != b), key=lambda p: pair_rank(*p, seed=seed))
    used: set[str] = set()
    first, rest = [], []
    for a, b in ranked:
        if a not in used and b not in used:
            first.append((a, b))
            used.update((a, b))
        else:
            rest.append((a, b))
    return (first + rest)[:n]


# ------------------------------------------------------------------ result store
class ResultStore:
    """One JSON file per finished item in ``folder`` (``<key>.json``), written atomically.

    A benchmark writes an item's outputs first and its result last, so "the result
    exists" means "the item is done"; an interrupted item is simply redone."""

    def __init__(self, folder):
        self.folder = Path(folder)

    @staticmethod
    def key(*parts) -> str:
        """File-name-safe key joining ``parts`` with ``__``."""
        return "__".join(re.sub(r"[^A-Za-z0-9._-]+", "-", str(p)) for p in parts)

    def path(self, key: str) -> Path:
        return self.folder / f"{key}.json"

    def get(self, key: str) -> dict | None:
        """The stored record, or None if absent or unreadable (then it is redone)."""
        p = self.path(key)
        try:
            return json.loads(p.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None

    def put(self, key: str, record: Mapping) -> Path:
        self.folder.mkdir(parents=True, exist_ok=True)
        return write_json(self.path(key), dict(record), overwrite=True)

    def keys(self) -> list[str]:
        return sorted(p.stem for p in self.folder.glob("*.json") if not p.name.startswith("."))


# ------------------------------------------------------------------------ tables
@dataclass(frozen=True)
class Column:
    """A table column: row-dict ``key``, Markdown ``title`` and number format ``fmt``
    (a format spec such as ``".2f"``, or a callable value -> str)."""

    key: str
    title: str
    fmt: str | Callable = ""

    def format(self, value) -> str:
        if value is None or (isinstance(value, float) and math.isnan(value)):
            return "–"
        if callable(self.fmt):
            return self.fmt(value)
        return format(value, self.fmt) if self.fmt and isinstance(value, (int, float)) else str(value)


def markdown_table(columns: Sequence[Column], rows: Iterable[Mapping]) -> str:
    """A GitHub Markdown table; numbers right-aligned."""
    rows = list(rows)
    lines = ["| " + " | ".join(c.title for c in columns) + " |"]
    align = []
    for c in columns:
        numeric = any(isinstance(r.get(c.key), (int, float)) and not isinstance(r.get(c.key), bool)
                      for r in rows)
        align.append("---:" if numeric else "---")
    lines.append("| " + " | ".join(align) + " |")
    for r in rows:
        lines.append("| " + " | ".join(c.format(r.get(c.key)).replace("|", "\\|") for c in columns) + " |")
    return "\n".join(lines) + "\n"


def csv_table(columns: Sequence[Column], rows: Iterable[Mapping]) -> str:
    """CSV text with the column keys as header; full-precision numbers, empty for missing."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([c.key for c in columns])
    for r in rows:
        vals = []
        for c in columns:
            v = r.get(c.key)
            vals.append("" if v is None or (isinstance(v, float) and math.isnan(v)) else v)
        w.writerow(vals)
    return buf.getvalue()


def write_text(path, text: str) -> Path:
    """Write UTF-8 text atomically (replacing an existing file)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def write_figure(path, fig, *, dpi: int = 120) -> Path:
    """Save a matplotlib figure atomically and close it."""
    import matplotlib.pyplot as plt

    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format=path.suffix.lstrip(".") or "png", bbox_inches="tight")
    finally:
        plt.close(fig)
    return path


def json_safe(obj):
    """``obj`` with NaN / inf floats replaced by None (strict JSON has no NaN)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


def mean_finite(values: Iterable) -> float:
    """Mean of the finite values (NaN when there are none)."""
    from .._stats import finite_values

    a = finite_values(values)
    return float(a.mean()) if a.size else float("nan")


# ------------------------------------------------------------------------ grids
def _fit_cell(image, cell: int) -> np.ndarray:
    """uint8 RGB cell × cell: ``image`` scaled to fit, centred on mid-grey."""
    out = np.full((cell, cell, 3), 128, np.uint8)
    if image is None:
        return out
    img = to_uint8(np.asarray(image))
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    img = img[..., :3]
    h, w = img.shape[:2]
    s = cell / max(h, w)
    nh, nw = max(1, round(h * s)), max(1, round(w * s))
    img = cv2.resize(img, (nw, nh), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_CUBIC)
    y, x = (cell - nh) // 2, (cell - nw) // 2
    out[y:y + nh, x:x + nw] = img
    return out


def _put_text(img: np.ndarray, text: str, org, scale: float, color=(0, 0, 0), outline=None) -> None:
    font = cv2.FONT_HERSHEY_SIMPLEX
    thick = max(1, round(scale * 2))
    if outline is not None:
        cv2.putText(img, text, org, font, scale, outline, thick + 2, cv2.LINE_AA)
    cv2.putText(img, text, org, font, scale, color, thick, cv2.LINE_AA)


def _centred_text(img: np.ndarray, text: str, x0: int, width: int, y_base: int, scale: float) -> None:
    font = cv2.FONT_HERSHEY_SIMPLEX
    thick = max(1, round(scale * 2))
    while scale > 0.3 and cv2.getTextSize(text, font, scale, thick)[0][0] > width - 8:
        scale *= 0.9
    tw = cv2.getTextSize(text, font, scale, thick)[0][0]
    _put_text(img, text, (x0 + (width - tw) // 2, y_base), scale)


def image_grid(rows: Sequence[Sequence], *, col_titles: Sequence[str] = (),
               cell_labels: Sequence[Sequence[str | None]] | None = None, cell: int = 256,
               gap: int = 4, title_height: int = 36) -> np.ndarray:
    """uint8 RGB grid of images (float [0, 1] or uint8; ``None`` = empty grey cell).

    Each image is scaled to fit a ``cell`` px square; ``col_titles`` go in a white band
    on top, ``cell_labels[r][c]`` (optional) in the lower-left corner of a cell."""
    n_rows = len(rows)
    n_cols = max((len(r) for r in rows), default=len(col_titles))
    n_cols = max(n_cols, len(col_titles))
    if n_rows == 0 or n_cols == 0:
        raise BadInputError("image grid needs at least one row and one column")
    top = title_height if col_titles else 0
    H = top + n_rows * cell + (n_rows + 1) * gap
    W = n_cols * cell + (n_cols + 1) * gap
    grid = np.full((H, W, 3), 255, np.uint8)
    scale = cell / 256 * 0.65
    for c, title in enumerate(col_titles):
        _centred_text(grid, str(title), gap + c * (cell + gap), cell, top - 11, scale)
    for r, row in enumerate(rows):
        y = top + gap + r * (cell + gap)
        for c in range(n_cols):
            x = gap + c * (cell + gap)
            grid[y:y + cell, x:x + cell] = _fit_cell(row[c] if c < len(row) else None, cell)
            label = cell_labels[r][c] if cell_labels and c < len(cell_labels[r]) else None
            if label:  # white text on a darkened strip, readable on any image
                font, ls = cv2.FONT_HERSHEY_SIMPLEX, scale * 0.8
                (tw, th), base = cv2.getTextSize(str(label), font, ls, 1)
                strip = grid[y + cell - th - base - 8:y + cell, x:x + min(cell, tw + 12)]
                strip[:] = strip // 3
                cv2.putText(grid, str(label), (x + 6, y + cell - base - 3), font, ls, (255, 255, 255), 1,
                            cv2.LINE_AA)
    return grid


def write_grid(path, rows, **kwargs) -> Path:
    """:func:`image_grid` written atomically as an image file."""
    return write_image(path, image_grid(rows, **kwargs), overwrite=True)


# --------------------------------------------------------------------- versions
def versions(extra: Sequence[str] = ()) -> dict[str, str]:
    """Versions of Python and the packages a benchmark result depends on."""
    from .. import __version__

    out = {"facetex": __version__, "python": platform.python_version()}
    for dist in ("numpy", "torch", "opencv-python-headless", "dlib-bin", "dlib", "scikit-image", *extra):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return out


def check_out_dir(out) -> Path:
    """Create the output folder (and parents); OutputError if that is impossible."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputError("output path exists and is not a folder: choose another --out", path=out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"cannot create output folder ({e.strerror}): choose another --out", path=out) from None
    return out


# ------------------------------------------------------------------ data and out
def data_root(data=None) -> Path:
    """The benchmarks' data folder: ``data`` (``--data``) or else ``$FACETEX_DATA``.

    Raises BadInputError when neither is given (a benchmark never defaults to a path of
    the machine it was written on) or the folder does not exist."""
    import os

    from ..io import check_input_dir

    value = data if data not in (None, "") else os.environ.get(DATA_ENV) or None
    if value is None:
        raise BadInputError(f"no data folder: pass --data DIR or set {DATA_ENV}=DIR (the folder holding "
                            "frl-london/, lfw/ and grid/, or the bench's own folder)")
    return check_input_dir(value, BadInputError, what="data folder")


def data_folder(root, sub: str | None) -> Path:
    """``root/sub`` when that exists (``root`` is the data root), else ``root`` itself (the
    bench's own folder was given). ``sub`` may also be an absolute or relative path."""
    root = Path(root)
    if not sub:
        return root
    p = Path(sub)
    if p.is_absolute() or p.exists() and not (root / p).exists():
        return p
    return root / p if (root / p).exists() else root


def default_out(bench: str) -> str:
    """Every benchmark writes to ``bench_out/<bench>`` unless ``--out`` says otherwise."""
    return f"bench_out/{bench}"


def add_bench_options(p, bench: str, data_help: str) -> None:
    """The options every ``facetex bench`` command shares, with the same names and defaults."""
    from ..cli._common import add_json, add_quiet

    p.add_argument("--data", metavar="DIR", default=None,
                   help=f"{data_help}; default ${DATA_ENV} (required when that is not set)")
    from ..cli._common import add_output

    add_output(p, dest="out", metavar="DIR", default=default_out(bench),
                   help=f"output folder (created; default {default_out(bench)}); gets run.json with the "
                        "command line, input hashes, settings and versions")
    add_json(p, "the run's summary")
    add_quiet(p)


def finish_bench(args, bench: str, out, files: Mapping | None = None, *, inputs=None, settings=None,
                 summary=None, table: str | None = None) -> Path:
    """Write the run folder's provenance sidecar ``OUT/run.json`` and report: ``wrote PATH``
    lines and the table (or the JSON summary with ``--json``)."""
    from .._provenance import provenance
    from ..cli._common import print_json, say

    out = Path(out)
    files = {k: str(v) for k, v in (files or {}).items()}
    params = {k: v for k, v in vars(args).items() if k not in ("func", "json", "quiet", "debug") and not callable(v)}
    table_md = out / "table.md"
    if table_md.is_file():  # the run's own table, then its settings and the spread of every mean
        extra = settings_and_spread_markdown(args, bench, out)
        table = table_md.read_text(encoding="utf-8").rstrip("\n") + "\n\n" + extra
        write_text(table_md, table)
    record = provenance(command=f"bench {bench}", seed=getattr(args, "seed", None), inputs=inputs or {},
                        params={**params, **(settings or {})}, outputs=list(files.values()),
                        summary=json_safe(no_image_data(summary)) if summary is not None else None)
    run_json = write_json(out / "run.json", record, overwrite=True)
    if getattr(args, "json", False):
        print_json(json_safe(no_image_data({"out": str(out), "files": {**files, "run": str(run_json)},
                                            "summary": summary})))
    else:
        if table:
            say(args, table.rstrip("\n"))
        say(args, *(f"wrote {v}" for v in files.values()), f"wrote {run_json}")
    return run_json


def non_default_settings(settings: Mapping, defaults: Mapping) -> dict:
    """The settings whose value differs from ``defaults`` (keys missing there count as set)."""
    return {k: v for k, v in settings.items() if k not in defaults or defaults[k] != v}


def no_image_data(obj, *, max_list: int = 4096):
    """``obj`` without image data: arrays become ``{"array": shape, "dtype"}`` and an
    ``"images"`` entry of a mapping is dropped, so a benchmark's JSON stays small."""
    if isinstance(obj, np.ndarray):
        if obj.size <= 16:
            return obj.tolist()
        return {"array": list(obj.shape), "dtype": str(obj.dtype)}
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Mapping):
        return {k: no_image_data(v, max_list=max_list) for k, v in obj.items() if k != "images"}
    if isinstance(obj, (list, tuple)):
        if len(obj) > max_list and all(isinstance(v, (int, float)) for v in obj[:16]):
            return {"list_of": len(obj)}
        return [no_image_data(v, max_list=max_list) for v in obj]
    return obj


def write_figure_formats(stem, fig, *, formats: Sequence[str] = ("png", "svg", "pdf"), dpi: int = 150) -> list[Path]:
    """Save a matplotlib figure as ``stem.png``, ``stem.svg`` and ``stem.pdf`` (vector for
    papers), atomically, then close it."""
    import matplotlib.pyplot as plt

    stem = Path(stem)
    out = []
    try:
        for fmt in formats:
            path = stem.with_name(f"{stem.name}.{fmt}")
            with atomic_path(path) as tmp:
                meta = {"svg": {"Date": None}, "pdf": {"CreationDate": None}}.get(fmt)  # reproducible bytes
                fig.savefig(tmp, dpi=dpi, format=fmt, bbox_inches="tight", metadata=meta)
            out.append(path)
    finally:
        plt.close(fig)
    return out


def settings_and_spread_markdown(args, bench: str, out) -> str:
    """Markdown: the options of this run that differ from the command's defaults, and per method
    the mean ± sample std and the 95 % CI of each key metric over the run's items (pairs,
    targets, clips), read back from the run folder as ``facetex report`` reads it."""
    from .._methods import method_title
    from ..errors import FacetexError
    from ..report.compare import KEY_METRICS, interval_summary
    from ..report.html import command_defaults
    from ..report.runs import load_run

    defaults = command_defaults(f"bench {bench}")
    skip = {"out", "json", "quiet", "overwrite", "func", "debug"}
    nd = {k: v for k, v in vars(args).items() if k in defaults and k not in skip
          and (list(v) if isinstance(v, tuple) else v) != (list(defaults[k]) if isinstance(defaults[k], tuple)
                                                           else defaults[k])}
    lines = ["## Settings of this run", "",
             "Options that differ from the defaults of `facetex bench " + bench + "`: " +
             (", ".join(f"`--{k.replace('_', '-')} {','.join(map(str, v)) if isinstance(v, (list, tuple)) else v}`"
                        for k, v in nd.items()) or "none") + ". All settings, input hashes and versions: `run.json`.",
             ""]
    try:
        run = load_run(out)
        rows = interval_summary(run, [k for k in KEY_METRICS if k in run.metric_names])
    except FacetexError:
        rows = []
    if rows:
        lines += ["## Spread", "",
                  "Mean over the items and its bootstrap 95 % interval (scipy.stats.bootstrap, BCa), inside the "
                  "metric's range; no interval below 5 items; n items.", "",
                  "| method | metric | n | mean | 95 % interval |", "|---|---|---:|---:|---:|"]
        for r in rows:
            ci = "–" if not math.isfinite(r["lo"]) else f"[{r['lo']:.4g}, {r['hi']:.4g}]"
            lines.append(f"| {method_title(r['method'])} | {r['metric']} | {r['n']} | {r['mean']:.4g} | {ci} |")
        lines.append("")
    return "\n".join(lines)
