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

__all__ = [
    "list_portraits", "select_pairs", "ResultStore", "Column", "markdown_table", "csv_table",
    "write_text", "write_figure", "image_grid", "write_grid", "mean_finite", "json_safe", "versions",
    "check_out_dir",
]

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


def select_pairs(ids: Sequence[str], n: int, *, seed: int = 0) -> list[tuple[str, str]]:
    """``n`` ordered (content, style) pairs of *different* ids, deterministic per ``seed``.

    The ids are shuffled and paired off first (each person in at most one pair while
    that is possible), further pairs are drawn from the remaining ordered pairs. The
    first k pairs do not depend on ``n``, so a longer run extends a shorter one.
    Fewer than ``n`` pairs are returned when fewer exist (m people give m(m-1))."""
    ids = sorted(set(ids))
    if len(ids) < 2:
        raise BadInputError(f"need at least 2 different people to pair, got {len(ids)}")
    if n < 1:
        raise BadInputError(f"number of pairs must be at least 1, got {n}")
    rng = np.random.default_rng(seed)
    order = [ids[i] for i in rng.permutation(len(ids))]
    pairs = [(order[i], order[i + 1]) for i in range(0, len(order) - 1, 2)]
    if n > len(pairs):
        taken = set(pairs)
        rest = [(a, b) for a in ids for b in ids if a != b and (a, b) not in taken]
        pairs += [rest[i] for i in rng.permutation(len(rest))]
    return pairs[:n]


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
    a = np.array([v for v in values if v is not None], dtype=np.float64)
    a = a[np.isfinite(a)]
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
