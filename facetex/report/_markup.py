"""HTML building blocks of the report (:mod:`facetex.report.html`): escaping, WebP data URIs, markdown
tables, number formats, the page's figure and script registry."""

from __future__ import annotations

import base64
import html
import io
import math
import os
import re
from pathlib import Path
from typing import Sequence

import numpy as np

from .._methods import TRANSFER_METHODS, method_title
from .compare import (
    _fmt,
)

__all__ = [
    "ZOOM_REGIONS",
    "THUMB_SIDE",
    "MIN_ZOOM_PX",
    "MAX_IMAGE_ROWS",
]


#: face regions zoomed at native resolution (crops placed at the content's landmarks)
ZOOM_REGIONS = ("forehead", "left cheek", "right cheek", "upper lip", "chin", "eyes")
THUMB_SIDE = 240  # px, the longer side of a thumbnail
#: rows of an item table with thumbnails and zooms; later rows show metrics and file links only
#: (10 000 items' images would make a page of GBs, issue 23)
MAX_IMAGE_ROWS = 200
MIN_ZOOM_PX = 200  # a zoom crop is shown at least this tall, enlarged by a whole factor (pixels stay square)
THUMB_QUALITY, CROP_QUALITY, SHEET_QUALITY = 75, 80, 78  # WebP qualities (0-100)


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def _data_uri(data: bytes, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


def _webp(img: np.ndarray, *, quality: int, max_side: int | None = None) -> str:
    """A WebP data URI of ``img`` (float [0, 1] or uint8 RGB), shrunk (area averaging) to
    ``max_side`` when larger; crops are passed without ``max_side``: their pixels are kept."""
    from PIL import Image

    from ..io import to_uint8

    a = to_uint8(np.asarray(img))
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    im = Image.fromarray(np.ascontiguousarray(a[..., :3]))
    if max_side is not None and max(im.size) > max_side:
        im.thumbnail((max_side, max_side), Image.Resampling.BOX)
    buf = io.BytesIO()
    im.save(buf, "WEBP", quality=quality, method=4)
    return _data_uri(buf.getvalue(), "image/webp")


def _fig_uri(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    try:
        # a fixed salt: matplotlib otherwise names the SVG's elements by random ids, and the same runs
        # would give another file each time
        with plt.rc_context({"svg.hashsalt": "facetex"}):
            fig.savefig(buf, format="svg", bbox_inches="tight", metadata={"Date": None})
    finally:
        plt.close(fig)
    return _data_uri(buf.getvalue(), "image/svg+xml")


_CELL_SPLIT = re.compile(r"(?<!\\)\|")
_SEPARATOR_CELL = re.compile(r"^\s*:?-{1,}:?\s*$")


def _md_cells(line: str) -> list[str]:
    """The cells of one Markdown pipe-table line (``\\|`` is a literal bar, not a border)."""
    s = line.strip()
    s = s[1:] if s.startswith("|") else s
    s = s[:-1] if s.endswith("|") and not s.endswith("\\|") else s
    cells = [c.strip().replace("\\|", "|") for c in _CELL_SPLIT.split(s)]
    # a method id in a table written before the one-name rule is shown by its name, as everywhere else
    return [method_title(c) if c in TRANSFER_METHODS else c for c in cells]


def _is_separator(cells: Sequence[str]) -> bool:
    """Whether a table line is the header/body separator (``---|:--:|---:``)."""
    return bool(cells) and all(_SEPARATOR_CELL.match(c) for c in cells)


def _markdown_table(md: str) -> str:
    """The pipe tables and text lines of a run's Markdown file as HTML (headings, paragraphs);
    the separator line under a table's header is markup, never a data row."""
    out, rows = [], []

    def flush():
        if not rows:
            return
        head, *body = rows
        body = [r for r in body if not _is_separator(r)]
        out.append("<table class='md'><thead><tr>" + "".join(f"<th>{_e(c)}</th>" for c in head) +
                   "</tr></thead><tbody>" + "".join("<tr>" + "".join(f"<td>{_e(c)}</td>" for c in r) + "</tr>"
                                                    for r in body) + "</tbody></table>")
        rows.clear()

    for line in md.splitlines():
        s = line.strip()
        if s.startswith("|") and s.endswith("|") and len(s) > 1:
            rows.append(_md_cells(s))
            continue
        flush()
        if s.startswith("#"):
            level = min(6, len(s) - len(s.lstrip("#")) + 3)
            out.append(f"<h{level}>{_e(s.lstrip('#').strip())}</h{level}>")
        elif s:
            out.append(f"<p>{_e(s)}</p>")
    flush()
    return "\n".join(out)


def _num(v) -> float:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else math.nan


def _interval_text(r: dict, digits: int = 3) -> str:
    """``mean [lo, hi]`` (or the mean alone without an interval) as HTML."""
    if r["n"] == 0:
        return "–"
    mean = _e(_fmt(r["mean"], digits + 1))
    if not math.isfinite(r["lo"]):
        return f"{mean}"
    return f"{mean} <span class='ci'>[{_e(_fmt(r['lo'], digits))}, {_e(_fmt(r['hi'], digits))}]</span>"


def _signed(v, digits: int = 3) -> str:
    t = _fmt(v, digits)
    return t if t.startswith(("-", "–")) else "+" + t


class _Page:
    """The page being built: its sections (for the table of contents) and a counter for ids."""

    def __init__(self, link_base: Path | None):
        self.toc: list[tuple[int, str, str]] = []
        self.link_base = link_base
        self.n = 0

    def heading(self, level: int, anchor: str, title: str, extra: str = "") -> str:
        self.toc.append((level, anchor, title))
        return f"<h{level} id='{_e(anchor)}'>{_e(title)}{extra}</h{level}>"

    def uid(self, prefix: str) -> str:
        self.n += 1
        return f"{prefix}{self.n}"

    def link(self, path: Path, label: str) -> str:
        """A link to a file of a run folder, relative to the report's folder when there is one."""
        p = Path(path)
        if self.link_base is not None:
            try:
                href = Path(os.path.relpath(p.resolve(), self.link_base.resolve())).as_posix()
            except ValueError:  # another drive
                href = p.resolve().as_uri()
        else:
            href = p.resolve().as_uri()
        return f"<a href='{_e(href)}' title='{_e(p)}'>{_e(label)}</a>"

    def toc_html(self) -> str:
        parts, depth = ["<nav id='toc' aria-label='contents'><b>Contents</b>"], 0
        for level, anchor, title in self.toc:
            lvl = level - 1
            while depth < lvl:
                parts.append("<ol>")
                depth += 1
            while depth > lvl:
                parts.append("</ol>")
                depth -= 1
            parts.append(f"<li><a href='#{_e(anchor)}'>{_e(title)}</a></li>")
        parts.append("</ol>" * depth + "</nav>")
        return "".join(parts)


