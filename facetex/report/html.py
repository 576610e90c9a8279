"""``facetex report``: one self-contained HTML page for one or more run folders.

Everything is inside the file (images as WebP data URIs, CSS and a small script), so it can
be mailed or archived. A transfer bench reads like a paper's results section:

1. FaceTex Table 1 beside ours: method × metric, our mean with its bootstrap 95 % interval
   (inside each metric's range; no interval below :data:`facetex._stats.MIN_N_INTERVAL` pairs)
   next to the paper's value;
2. paired differences: every method against "no transfer" and the methods against each other,
   per pair, with the interval of the mean difference and how many pairs each side wins;
3. figures (per-pair metrics, paired differences);
4. a sortable per-pair table: thumbnails, the metrics per method, the per-pair ranking and
   links to the files; a click on a row opens the pair in a viewer with its images and
   native-resolution zooms (forehead, cheeks, upper lip, chin, eyes, shown ≥ 200 px with
   whole-pixel enlargement);
5. settings and provenance, every metric's interval and the run's own tables (folded).

Persona leave-out folders get the leave-out table in the paper's Fig. 5 order with paired
differences against the static average, the bench's contact sheets and a sortable
per-target table; puppet folders the targets, a sortable per-run table with the worst run
marked, and the worst runs' sheets. Methods have one name and one order everywhere
(:mod:`facetex._methods`). Thumbnails are WebP (≤ 240 px); only zoom crops are at full
resolution, so ten pairs stay under 2 MB.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
import os
import re
from pathlib import Path
from typing import Sequence

import numpy as np

from .._methods import METHOD_COLOURS, NO_TRANSFER, TRANSFER_METHODS, method_title
from .compare import (KEY_METRICS, _fmt, _order, best_counts, cell, compare_rows, interval_summary, method_pairs,
                      paired_differences)
from .metric_info import PAIR_METRICS, TABLE1_METRICS, metric_info
from .runs import Item, Run

__all__ = ["build_report", "ZOOM_REGIONS", "THUMB_SIDE", "MAX_IMAGE_ROWS", "MIN_ZOOM_PX"]

_DEFAULTS = {"preset": "default", "seed": 0, "size": None, "device": "cpu", "iters": None}
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


# ---------------------------------------------------------------- transfer: Table 1 and differences


def _table1(run: Run) -> str:
    """FaceTex Table 1 (rows: metrics; columns: methods, the paper's value beside ours)."""
    methods = run.methods
    transfer = [m for m in methods if m != NO_TRANSFER]
    metrics = [m for m in TABLE1_METRICS if m in run.metric_names] + \
              [m for m in ("identity_content", "time_s") if m in run.metric_names]
    if not methods or not metrics:
        return "<p>No per-pair metrics in this run.</p>"
    summary = {(r["method"], r["metric"]): r for r in interval_summary(run, metrics)}
    head1 = "<tr><th rowspan='2'>metric</th>" + "".join(
        f"<th colspan='{1 if m == NO_TRANSFER else 2}' class='m'>{_e(method_title(m))}</th>" for m in methods) \
        + "<th rowspan='2'>best on (pairs)</th></tr>"
    head2 = "<tr>" + "".join("<th>ours</th>" if m == NO_TRANSFER else "<th class='paper'>paper</th><th>ours</th>"
                             for m in methods) + "</tr>"
    body = []
    n_items = max((summary[k]["n"] for k in summary), default=0)
    for metric in metrics:
        info = metric_info(metric)
        cells = [f"<th class='metric' title='{_e(metric)}'>{_e(info.title)}{info.arrow}</th>"]
        for m in methods:
            if m != NO_TRANSFER:
                ref = run.paper.get(m, {}).get(metric)
                cells.append(f"<td class='paper'>{_e(_fmt(ref)) if ref is not None else '–'}</td>")
            r = summary.get((m, metric))
            cells.append(f"<td>{_interval_text(r) if r else '–'}</td>")
        wins = best_counts(run, metric, transfer)
        cells.append("<td class='wins'>" + (", ".join(f"{_e(method_title(m))} {k}" for m, k in wins.items())
                                            if info.better and len(transfer) > 1 else "–") + "</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    from .._stats import MIN_N_INTERVAL

    note = (f"Ours: mean over {n_items} pairs and its bootstrap 95 % interval (scipy.stats.bootstrap, BCa, 9999 "
            f"resamples), never outside the metric's range; fewer than {MIN_N_INTERVAL} pairs: the mean alone. "
            "↓ lower is better, ↑ higher is better (E(xt, xs) and S(xt, xc) have no better side). "
            "“best on”: pairs where the method has the best value of the transfer methods. ")
    if run.paper:
        note += f"Paper: {run.paper_source}; other data, shown as a reference, not a target."
    return (f"<table class='t1'><thead>{head1}{head2}</thead><tbody>{''.join(body)}</tbody></table>"
            f"<p class='note'>{_e(note)}</p>")


def _pair_label(a: str, b: str) -> str:
    return f"{method_title(a)} − {method_title(b)}"


def _paired(run: Run, metrics: Sequence[str]) -> tuple[str, list[dict]]:
    """The paired-difference table (rows: method pairs; columns: metrics) and its rows."""
    pairs = method_pairs(run)
    metrics = [m for m in metrics if m in run.metric_names]
    if not pairs or not metrics:
        return "", []
    rows = [paired_differences(run, a, b, k) for a, b in pairs for k in metrics]
    head = "<tr><th>difference (per pair)</th>" + "".join(
        f"<th title='{_e(k)}'>{_e(metric_info(k).title)}{metric_info(k).arrow}</th>" for k in metrics) + "</tr>"
    body = []
    for a, b in pairs:
        cells = [f"<th class='m'>{_e(_pair_label(a, b))}</th>"]
        for k in metrics:
            r = next(r for r in rows if (r["a"], r["b"], r["metric"]) == (a, b, k))
            if r["n"] == 0:
                cells.append("<td>–</td>")
                continue
            mean = _e(_signed(r["mean"]))
            ci = "" if not math.isfinite(r["lo"]) else \
                f" <span class='ci'>[{_e(_fmt(r['lo'], 3))}, {_e(_fmt(r['hi'], 3))}]</span>"
            decided = (r["lo"] > 0 or r["hi"] < 0) if math.isfinite(r["lo"]) else False
            tied = f" ({r['ties']} tied)" if r["ties"] else ""
            wins = "" if r["wins_a"] is None else (
                f"<br><span class='wins' title='pairs where {_e(method_title(a))} / {_e(method_title(b))} is better'>"
                f"wins {r['wins_a']}–{r['wins_b']}{tied} of {r['n']}</span>")
            cells.append(f"<td{' class=decided' if decided else ''}>{mean}{ci}{wins}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    note = ("Each cell: the mean over the pairs of (first − second) with its bootstrap 95 % interval (no interval "
            "below 5 pairs); bold when the interval excludes 0. “wins a–b of n”: pairs where the first / the second "
            "method is better on a metric with a better side.")
    return (f"<table class='paired'><thead>{head}</thead><tbody>{''.join(body)}</tbody></table>"
            f"<p class='note'>{_e(note)}</p>"), rows


def _transfer_figures(run: Run, diff_rows: list[dict]) -> str:
    from .figures import differences_figure, metrics_figure

    metrics = [m for m in (*TABLE1_METRICS, "identity_content") if m in run.metric_names]
    parts = []
    if metrics and run.methods:
        series = {method_title(m): {k: run.values(m, k) for k in metrics} for m in run.methods}
        paper = {method_title(m): v for m, v in run.paper.items()}
        colours = {method_title(m): c for m, c in METHOD_COLOURS.items()}
        fig = metrics_figure(series, metrics, paper=paper or None, colours=colours,
                             titles={k: metric_info(k).title + metric_info(k).arrow for k in metrics},
                             title=f"{run.name}: per-pair metrics, means and bootstrap 95 % intervals")
        parts.append(f"<figure><img class='figure' alt='per-pair metrics of {_e(run.name)}' src='{_fig_uri(fig)}'>"
                     "<figcaption>Per-pair metrics: every pair a dot, the mean with its bootstrap 95 % interval, the "
                     "paper's values as hollow diamonds (other data).</figcaption></figure>")
    dm = [m for m in PAIR_METRICS if any(r["metric"] == m for r in diff_rows)]
    if dm:
        labels = {(r["a"], r["b"]): _pair_label(r["a"], r["b"]) for r in diff_rows}
        fig = differences_figure([r for r in diff_rows if r["metric"] in dm], dm, labels=labels,
                                 titles={k: metric_info(k).title + metric_info(k).arrow for k in dm},
                                 title="paired differences (first − second), per pair")
        parts.append(f"<figure><img class='figure' alt='paired differences of {_e(run.name)}' src='{_fig_uri(fig)}'>"
                     "<figcaption>Paired differences: every pair a dot, the mean difference with its bootstrap 95 % "
                     "interval; the line is 0 (no difference).</figcaption></figure>")
    return "".join(parts)


def _all_metrics(run: Run) -> str:
    rows = interval_summary(run)
    if not rows:
        return "<p>No per-item metrics in this run.</p>"
    body = "".join(
        f"<tr><td>{_e(method_title(r['method']))}</td><td>{_e(r['metric'])}</td><td>{r['n']}</td>"
        f"<td>{_interval_text(r)}</td><td>{_e(_fmt(r['paper'])) if r['paper'] is not None else '–'}</td></tr>"
        for r in rows)
    return (f"<details><summary>Every metric of every method ({len(rows)} rows): mean and bootstrap 95 % interval"
            "</summary><table class='metrics'><thead><tr><th>method</th><th>metric</th><th>n</th>"
            "<th>mean [95 % interval]</th><th>paper</th></tr></thead><tbody>" + body + "</tbody></table></details>")


# ---------------------------------------------------------------- per-item table, viewer, zooms


def _region_crops(it: Item) -> tuple[list[str], list[tuple[str, list]]] | None:
    """(column labels, [(region, [(uri, w, h) or None per column])]) of the item's zoom crops at
    native resolution, placed at the content's landmarks (scaled to each image's size: the
    outputs have the content's geometry), or None without a content image or a face in it."""
    from ..bench._zoom import zoom_boxes
    from ..errors import FacetexError
    from ..io import read_image
    from ..landmarks import detect_face

    if "content" not in it.images:
        return None
    try:
        content = read_image(it.images["content"])
        points = np.asarray(detect_face(content).points68, np.float64)
    except FacetexError:
        return None
    h0, w0 = content.shape[:2]
    columns = [("content", content)]
    for label, path in [*it.aligned.items(), *((k, v) for k, v in it.images.items() if k not in ("style", "content"))]:
        try:
            columns.append((label, read_image(path)))
        except FacetexError:
            continue
    if len(columns) < 2:
        return None
    regions = []
    for region in ZOOM_REGIONS:
        cells = []
        for _, img in columns:
            h, w = img.shape[:2]
            x, y, bw, bh = zoom_boxes(points * [w / w0, h / h0])[region]
            x0, y0, x1, y1 = max(0, x), max(0, y), min(w, x + bw), min(h, y + bh)
            if x1 - x0 < 2 or y1 - y0 < 2:
                cells.append(None)
                continue
            crop = img[y0:y1, x0:x1]
            cells.append((_webp(crop, quality=CROP_QUALITY), x1 - x0, y1 - y0))
        regions.append((region, cells))
    return [label for label, _ in columns], regions


def _zoom_table(crops) -> str:
    """One line per region, the images side by side (a line per region, not a table: the wide eye
    crops do not widen every column)."""
    labels, regions = crops
    rows = []
    for region, cells in regions:
        figs = []
        for label, c in zip(labels, cells):
            if c is None:
                continue
            uri, w, h = c
            k = max(1, math.ceil(MIN_ZOOM_PX / min(w, h)))  # a whole factor: every image pixel is k×k screen pixels
            figs.append(f"<figure><img class='crop' src='{uri}' width='{w * k}' height='{h * k}' data-native='{w}x{h}' "
                        f"data-scale='{k}' alt='{_e(region)}: {_e(method_title(label))}'><figcaption>"
                        f"<b>{_e(method_title(label))}</b> {w}×{h} px ×{k}</figcaption></figure>")
        rows.append(f"<div class='zrow'><div class='zlab'>{_e(region)}</div>{''.join(figs)}</div>")
    return f"<div class='zooms'>{''.join(rows)}</div>"


def _item_table(page: _Page, run: Run, group: str, *, metrics: Sequence[str], methods: Sequence[str] | None = None,
                rank_metrics: Sequence[str] = (), label_head: str = "pair", zooms: bool = True,
                extra_cols: Sequence[tuple[str, str]] = (), highlight=None) -> tuple[str, str]:
    """A sortable table of ``run``'s items (thumbnails, ``metrics`` per method, the per-item
    ranking on ``rank_metrics``, links) and the viewer sections its rows open.

    Returns (table HTML, viewer sections HTML)."""
    methods = list(methods if methods is not None else run.methods)
    metrics = [k for k in metrics if k in run.metric_names]
    cols = [(m, k) for k in metrics for m in methods if any(k in it.metrics.get(m, {}) for it in run.items)]
    has_images = any(it.images for it in run.items)
    head = [f"<th data-sort='num'>#</th><th data-sort='text'>{_e(label_head)}</th>"]
    if has_images:
        head.append("<th>images (click the row)</th>")
    head += [f"<th data-sort='num' title='{_e(k)}'>{_e(label)}</th>" for k, label in extra_cols]
    sub = (lambda m: f"<br><small>{_e(method_title(m))}</small>") if len(methods) > 1 else (lambda m: "")
    head += [f"<th data-sort='num' title='{_e(k)}: {_e(method_title(m))}'>{_e(metric_info(k).title)}"
             f"{metric_info(k).arrow}{sub(m)}</th>" for m, k in cols]
    head += [f"<th data-sort='text'>ranking by {_e(metric_info(k).title)}</th>" for k in rank_metrics]
    head.append("<th>files</th>")
    body, viewers = [], []
    for i, it in enumerate(run.items):
        vid = f"{group}-{i}"
        cls = " class='highlight'" if highlight and highlight(it) else ""
        cells = [f"<td data-v='{i + 1}'>{i + 1}</td><td class='lab'>{_e(it.label)}</td>"]
        shown = has_images and i < MAX_IMAGE_ROWS
        if has_images:
            thumbs = []
            for label, p in (it.images.items() if shown else ()):
                img = _read(p)
                if img is not None:
                    thumbs.append(f"<img class='thumb' src='{_webp(img, quality=THUMB_QUALITY, max_side=THUMB_SIDE)}' "
                                  f"alt='{_e(method_title(label))}: {_e(it.label)}' title='{_e(method_title(label))}' "
                                  f"data-label='{_e(method_title(label))}'>")
            cells.append(f"<td class='thumbs'>{''.join(thumbs)}</td>")
        for k, _ in extra_cols:
            v = _num(next((vals.get(k) for vals in it.metrics.values() if k in vals), None))
            cells.append(f"<td data-v='{v if math.isfinite(v) else ''}'>{_e(_fmt(v))}</td>")
        for m, k in cols:
            v = _num(it.metrics.get(m, {}).get(k))
            cells.append(f"<td data-v='{v if math.isfinite(v) else ''}'>{_e(_fmt(v))}</td>")
        for k in rank_metrics:
            info = metric_info(k)
            vals = [(m, _num(it.metrics.get(m, {}).get(k))) for m in methods]
            vals = [(m, v) for m, v in vals if math.isfinite(v)]
            vals.sort(key=lambda mv: mv[1], reverse=info.better == "higher")
            cells.append("<td class='rank'>" + " &gt; ".join(_e(method_title(m)) for m, _ in vals) + "</td>")
        links = "<br>".join(page.link(p, label) for label, p in it.files.items())
        cells.append(f"<td class='files'><details><summary>{len(it.files)}</summary>{links}</details></td>"
                     if it.files else "<td class='files'>–</td>")
        opens = f" data-open='{vid}'" if shown or not has_images else ""  # a row past the images opens nothing
        body.append(f"<tr{opens}{cls}>{''.join(cells)}</tr>")
        if shown:
            crops = _region_crops(it) if zooms else None
            viewers.append(f"<section class='vitem' id='{vid}' data-group='{group}' data-label='{_e(it.label)}' hidden>"
                           f"<h3>{_e(it.label)}</h3><div class='vthumbs'></div>"
                           + (("<h4>Native-resolution zooms (whole-pixel enlargement, no smoothing)</h4>"
                               + _zoom_table(crops)) if crops else "") + "</section>")
    table = (f"<div class='scroll'><table class='items sortable' data-group='{group}'><thead><tr>{''.join(head)}</tr>"
             f"</thead><tbody>{''.join(body)}</tbody></table></div>"
             "<p class='note'>Click a column header to sort (again: reverse); click a row to open its images and "
             "zooms (← → previous / next, Esc closes)."
             + (f" Images of the first {MAX_IMAGE_ROWS} of {len(run.items)} rows only (a page of every row's images "
                "would be too large): the others link their files." if has_images and len(run.items) > MAX_IMAGE_ROWS
                else "") + "</p>")
    return table, "".join(viewers)


def _read(path):
    """The image at ``path`` (float RGB), or None when it cannot be read (it is then left out)."""
    from ..errors import FacetexError
    from ..io import read_image

    try:
        return read_image(path)
    except FacetexError:
        return None


# ---------------------------------------------------------------- persona and puppet benches

PERSONA_METRICS = ("face_ssim", "mouth_ssim", "eyes_ssim", "face_grad_corr", "face_colour_diff")
PUPPET_METRICS = ("mouth_slope", "mouth_r", "cheek_de", "eye_ratio", "sharp", "id_closer", "id_puppet", "flicker",
                  "fps", "fail_score")


def _sheet(path: Path, caption: str, *, max_side: int = 1600) -> str:
    img = _read(path)
    if img is None:
        return ""
    h, w = img.shape[:2]
    shrunk = max(h, w) > max_side
    return (f"<figure><img class='sheet' alt='{_e(caption)}' src='{_webp(img, quality=SHEET_QUALITY, max_side=max_side)}'>"
            f"<figcaption>{_e(caption)} ({w}×{h} px{', shown shrunk: the file has every pixel' if shrunk else ''})"
            "</figcaption></figure>")


def _leave_out_table(run: Run) -> str:
    metrics = [k for k in PERSONA_METRICS if k in run.metric_names]
    if not metrics:
        return "<p>No per-target metrics in this run.</p>"
    summary = {(r["method"], r["metric"]): r for r in interval_summary(run, metrics)}
    base = run.method_order[0] if run.method_order[0] in run.methods else None
    ssim = [k for k in metrics if k.endswith("_ssim")]
    head = "<tr><th>method (Fig. 5 order)</th><th>targets</th>" + "".join(
        f"<th>{_e(metric_info(k).title)}{metric_info(k).arrow}</th>" for k in metrics) + "".join(
        f"<th>Δ {_e(metric_info(k).title)} vs {_e(base)}</th>" for k in (ssim if base else [])) + "</tr>"
    body = []
    for m in run.methods:
        n = max((summary[(m, k)]["n"] for k in metrics if (m, k) in summary), default=0)
        cells = [f"<th class='m'>{_e(m)}</th><td>{n}</td>"]
        cells += [f"<td>{_interval_text(summary[(m, k)]) if (m, k) in summary else '–'}</td>" for k in metrics]
        for k in (ssim if base else []):
            if m == base:
                cells.append("<td>–</td>")
                continue
            r = paired_differences(run, m, base, k)
            ci = "" if not math.isfinite(r["lo"]) else \
                f" <span class='ci'>[{_e(_fmt(r['lo'], 3))}, {_e(_fmt(r['hi'], 3))}]</span>"
            wins = "" if r["wins_a"] is None else f"<br><span class='wins'>better on {r['wins_a']} of {r['n']}</span>"
            cells.append(f"<td>{_e(_signed(r['mean']))}{ci}{wins}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    note = ("Rows in Tom Hanks Fig. 5's order: static average, weighted average, pre-warped average, the paper's "
            "method, ours. Mean over the held-out targets with its bootstrap 95 % interval; Δ: per-target "
            "difference from the static average, its mean and interval, and on how many targets the method is better.")
    return (f"<table class='t1'><thead>{head}</thead><tbody>{''.join(body)}</tbody></table>"
            f"<p class='note'>{_e(note)}</p>")


def _target_text(t) -> str:
    if not isinstance(t, (list, tuple)) or len(t) != 2:
        return "–"
    lo, hi = t
    if lo is not None and hi is not None:
        return f"{_fmt(lo)}–{_fmt(hi)}"
    return f"≥ {_fmt(lo)}" if lo is not None else (f"≤ {_fmt(hi)}" if hi is not None else "–")


def _meets(v: float, t) -> bool | None:
    if not isinstance(t, (list, tuple)) or len(t) != 2 or not math.isfinite(v):
        return None
    lo, hi = t
    return (lo is None or v >= lo) and (hi is None or v <= hi)


def _puppet_summary(run: Run) -> str:
    metrics = [k for k in PUPPET_METRICS if k in run.metric_names]
    if not metrics:
        return "<p>No per-run metrics in this run.</p>"
    targets = run.extra.get("targets") or {}
    summary = {r["metric"]: r for r in interval_summary(run, metrics)}
    body = []
    for k in metrics:
        vals = [v for v in run.values("puppet", k) if math.isfinite(v)]
        t = targets.get(k)
        met = [_meets(v, t) for v in vals]
        met_txt = "–" if t is None else f"{sum(1 for x in met if x)} of {len(vals)}"
        body.append(f"<tr><th class='metric' title='{_e(k)}'>{_e(metric_info(k).title)}{metric_info(k).arrow}</th>"
                    f"<td>{_interval_text(summary[k]) if k in summary else '–'}</td>"
                    f"<td>{_e(_fmt(min(vals))) if vals else '–'}</td><td>{_e(_fmt(max(vals))) if vals else '–'}</td>"
                    f"<td>{_e(_target_text(t))}</td><td>{met_txt}</td></tr>")
    return ("<table class='t1'><thead><tr><th>metric</th><th>mean [95 % interval]</th><th>min</th><th>max</th>"
            "<th>target</th><th>runs meeting it</th></tr></thead><tbody>" + "".join(body) + "</tbody></table>"
            "<p class='note'>Over the runs (persona × driver clip); intervals: bootstrap 95 %, inside each metric's "
            "range. Fail score: failed targets plus their relative shortfalls (0 = every target met).</p>")


def _worst_item(run: Run):
    scored = [(it.metrics.get("puppet", {}).get("fail_score", -math.inf), i) for i, it in enumerate(run.items)]
    if not scored:
        return None
    best = max(scored)
    return run.items[best[1]] if best[0] > 0 else None


# ---------------------------------------------------------------- shared sections
def command_defaults(command: str) -> dict:
    """The defaults of a facetex command's options ({dest: default}), from its parser."""
    import argparse

    from ..cli import build_parser

    parser = build_parser()
    for word in command.split(":")[0].split():
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs or word not in subs[0].choices:
            return {}
        parser = subs[0].choices[word]
    return {a.dest: a.default for a in parser._actions if a.dest not in ("help", "debug") and a.option_strings}


def _normal(v):
    return list(v) if isinstance(v, tuple) else v


def _settings_html(run: Run) -> str:
    s = {k: v for k, v in run.settings.items() if k != "versions"}
    non_default = {k: v for k, v in s.items() if k in _DEFAULTS and _DEFAULTS[k] != v}
    p = (run.provenance or {}).get("params") or {}
    if p and (run.provenance or {}).get("command"):
        defaults = command_defaults(run.provenance["command"])
        for k, v in p.items():
            if k in defaults and k not in ("out", "data", "json", "quiet", "overwrite") \
                    and _normal(defaults[k]) != _normal(v):
                non_default[k] = v
                s.setdefault(k, v)
    parts = ["<table class='kv'>"]
    for k, v in s.items():
        mark = " class='nondefault' title='differs from the default'" if k in non_default else ""
        parts.append(f"<tr{mark}><th>{_e(k)}</th><td>{_e(json.dumps(v) if not isinstance(v, str) else v)}</td></tr>")
    parts.append("</table>")
    nd = ", ".join(f"{k} = {json.dumps(v)}" for k, v in non_default.items()) or "none"
    return f"<p><b>Non-default settings:</b> {_e(nd)}</p>" + "".join(parts)


def _provenance(run: Run) -> str:
    parts = []
    if run.provenance:
        p = run.provenance
        parts.append(f"<p><b>Command:</b> <code>{_e(p.get('command_line', ''))}</code> "
                     f"({_e(p.get('created_utc', ''))})</p>")
        v = p.get("versions") or {}
        parts.append("<p><b>Versions:</b> " + _e(", ".join(f"{k} {val}" for k, val in v.items() if val)) + "</p>")
        parts.append(f"<details><summary>run.json</summary><pre>{_e(json.dumps(p, indent=1))}</pre></details>")
    if run.sidecars:
        first = next(iter(run.sidecars.items()))
        params = first[1].get("params") or {}
        parts.append(f"<details><summary>Sidecar parameters ({len(run.sidecars)} sidecars; the first: {_e(first[0])})"
                     f"</summary><pre>{_e(json.dumps(params, indent=1, default=str)[:20000])}</pre></details>")
    return "".join(parts) or "<p>No provenance record (run.json) in this folder.</p>"



def _comparison(runs: Sequence[Run]) -> str:
    rows = compare_rows(runs)
    if not rows:
        return "<p>The runs have no metrics in common.</p>"
    head = ("<tr><th>method</th><th>metric</th>" + "".join(f"<th>[{i + 1}] {_e(r.name)}</th>" for i, r in enumerate(runs))
            + "".join(f"<th>Δ [{i + 1}] − [1]</th>" for i in range(1, len(runs))) + "</tr>")
    body = "".join(
        f"<tr><td>{_e(method_title(r['method']))}</td><td>{_e(r['metric'])}</td>"
        + "".join(f"<td>{_e(cell(c))}</td>" for c in r["runs"])
        + "".join(f"<td>{_e(_fmt(d))}</td>" for d in r["delta"][1:]) + "</tr>" for r in rows)
    legend = "".join(f"<li>[{i + 1}] <code>{_e(r.path)}</code> — {_e(r.kind)}, {len(r.items)} items</li>"
                     for i, r in enumerate(runs))
    from .figures import metrics_figure

    fig_html = ""
    common = [m for m in KEY_METRICS if all(m in r.metric_names for r in runs)][:6]
    if common:
        series = {}
        for i, r in enumerate(runs):
            for m in r.methods:
                series[f"[{i + 1}] {method_title(m)}"] = {k: r.values(m, k) for k in common}
        fig = metrics_figure(series, common, title="runs side by side")
        fig_html = f"<figure><img class='figure' alt='comparison' src='{_fig_uri(fig)}'></figure>"
    return (f"<ul>{legend}</ul><table class='compare'>{head}{body}</table>"
            "<p class='note'>mean ± sample std (n items); Δ: difference of the means from run [1].</p>" + fig_html)


_CSS = """
body{font:14px/1.45 system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:0 auto;max-width:1500px;padding:0 18px 60px;color:#222}
h1{font-size:22px;margin:14px 0 4px}h2{border-bottom:2px solid #ddd;padding-bottom:3px;margin-top:30px;font-size:19px}
h3{margin-top:22px;font-size:16px}
#toc{font-size:13px;background:#f7f7f9;border:1px solid #e3e3e8;padding:6px 12px;margin:8px 0 4px;columns:2 340px}
#toc ol{margin:2px 0;padding-left:18px}#toc li{break-inside:avoid}
table{border-collapse:collapse;margin:6px 0 10px;font-size:13px}th,td{border:1px solid #ddd;padding:3px 7px;text-align:right;vertical-align:top}
thead th{background:#f0f0f0;text-align:center}th.m,th.metric,td.lab,td.rank,td.files{text-align:left}
table.t1 td,table.paired td{white-space:nowrap}table.t1 td.paper,table.t1 th.paper{background:#f7f3ea;color:#555}
td.wins,span.wins{color:#555;font-size:12px}span.ci{color:#555;font-size:12px}td.decided{font-weight:600}
table.kv th{text-align:left;background:#f6f6f6}table.kv td{text-align:left;font-family:monospace}
tr.nondefault th,tr.nondefault td{background:#fff4d6}
.note{color:#666;font-size:12px;max-width:1100px}
.scroll{overflow-x:auto}
table.items tbody tr{cursor:pointer}table.items tbody tr:hover{background:#eef4ff}
table.items tr.highlight{background:#ffe9e6}
table.sortable th[data-sort]{cursor:pointer;user-select:none}
table.sortable th[aria-sort=ascending]::after{content:" ▲"}table.sortable th[aria-sort=descending]::after{content:" ▼"}
td.files summary{cursor:pointer;color:#2a5db0}td.files details[open]{white-space:nowrap}
td.thumbs{white-space:nowrap;text-align:left}td.thumbs img{height:64px;width:auto;margin-right:2px;border:1px solid #ccc}
img.figure{max-width:100%}img.sheet{max-width:100%}
#viewer{display:none;position:fixed;inset:0;background:#161616;z-index:10;overflow:auto;color:#eee}
#viewer.open{display:block}
#viewer .bar{position:sticky;top:0;background:#0d0d0d;padding:6px 10px;display:flex;gap:8px;align-items:center;z-index:1}
#viewer button{background:#333;color:#eee;border:1px solid #555;padding:3px 10px;cursor:pointer;border-radius:3px}
#viewer section{padding:4px 16px 30px}#viewer h3,#viewer h4{color:#eee}
#viewer .vthumbs img{height:auto;width:auto;max-width:none;margin:0 6px 6px 0;border:1px solid #444}
#viewer .vthumbs figure{display:inline-block;margin:0 8px 8px 0;text-align:center;font-size:12px}
.zrow{display:flex;flex-wrap:wrap;gap:10px;align-items:flex-start;margin:0 0 14px;border-top:1px solid #333;padding-top:6px}
.zlab{width:90px;font-weight:600}.zrow figure{margin:0;font-size:12px;color:#ccc}
img.crop{image-rendering:pixelated;max-width:none}
pre{background:#f7f7f7;padding:8px;overflow:auto;max-height:420px;font-size:12px}
code{background:#f3f3f3;padding:0 3px}
"""

_JS = r"""
(function(){
  function num(td){var v=td.getAttribute('data-v');return v===null||v===''?NaN:parseFloat(v);}
  // sortable tables: numbers by data-v (missing values last), text by its content
  Array.prototype.forEach.call(document.querySelectorAll('table.sortable'),function(table){
    var ths=table.tHead.rows[0].cells;
    Array.prototype.forEach.call(ths,function(th,col){
      if(!th.dataset.sort)return;
      th.addEventListener('click',function(){
        var asc=th.getAttribute('aria-sort')!=='ascending';
        Array.prototype.forEach.call(ths,function(o){o.removeAttribute('aria-sort');});
        th.setAttribute('aria-sort',asc?'ascending':'descending');
        var body=table.tBodies[0],rows=Array.prototype.slice.call(body.rows);
        rows.sort(function(a,b){
          var x,y;
          if(th.dataset.sort==='num'){x=num(a.cells[col]);y=num(b.cells[col]);
            if(isNaN(x)&&isNaN(y))return 0;if(isNaN(x))return 1;if(isNaN(y))return -1;return asc?x-y:y-x;}
          x=a.cells[col].textContent;y=b.cells[col].textContent;return asc?x.localeCompare(y):y.localeCompare(x);
        });
        rows.forEach(function(r){body.appendChild(r);});
      });
    });
  });
  // the viewer: a row's images (its thumbnails, at their own size) and its native-resolution zooms
  var viewer=document.getElementById('viewer'),caption=document.getElementById('viewer-caption'),current=null;
  function fill(sec){
    var box=sec.querySelector('.vthumbs');if(box.childElementCount)return;
    var row=document.querySelector('tr[data-open="'+sec.id+'"]');if(!row)return;
    Array.prototype.forEach.call(row.querySelectorAll('img.thumb'),function(t){
      var f=document.createElement('figure'),i=t.cloneNode();i.className='vthumb';
      var c=document.createElement('figcaption');c.textContent=t.dataset.label;f.appendChild(i);f.appendChild(c);box.appendChild(f);});
  }
  function open(id){
    var sec=document.getElementById(id);if(!sec)return;
    if(current)current.hidden=true;
    fill(sec);sec.hidden=false;current=sec;viewer.classList.add('open');viewer.scrollTop=0;
    caption.textContent=sec.dataset.label;
  }
  function step(d){
    if(!current)return;
    var table=document.querySelector('table.items[data-group="'+current.dataset.group+'"]');
    var ids=Array.prototype.map.call(table.tBodies[0].rows,function(r){return r.dataset.open;}).filter(function(x){return document.getElementById(x);});
    var k=ids.indexOf(current.id);open(ids[(k+d+ids.length)%ids.length]);
  }
  function close(){if(current)current.hidden=true;current=null;viewer.classList.remove('open');}
  document.addEventListener('click',function(e){
    if(e.target.closest('a,summary,details'))return;  // a link or the files list: not the viewer
    var tr=e.target.closest('tr[data-open]');if(tr)open(tr.dataset.open);
  });
  document.getElementById('viewer-close').addEventListener('click',close);
  document.getElementById('viewer-prev').addEventListener('click',function(){step(-1);});
  document.getElementById('viewer-next').addEventListener('click',function(){step(1);});
  document.addEventListener('keydown',function(e){
    if(!current)return;
    if(e.key==='Escape')close();else if(e.key==='ArrowRight')step(1);else if(e.key==='ArrowLeft')step(-1);
  });
})();
"""


def _run_sections(page: _Page, run: Run, r_i: int, multi: bool) -> tuple[list[str], list[str]]:
    """The sections of one run (HTML parts) and its viewer sections."""
    from .._stats import MIN_N_INTERVAL

    pre = f"r{r_i + 1}"
    lvl = 3 if multi else 2
    body, viewers = [], []
    n = len(run.items)
    if multi:
        body.append(page.heading(2, pre, f"[{r_i + 1}] {run.name}", f" <small>({_e(run.kind)}, {n} items)</small>"))
    body.append(f"<p class='note'>{_e(run.kind)}, {n} items: <code>{_e(run.path)}</code>"
                + (f"; with n = {n} below {MIN_N_INTERVAL} no intervals are drawn." if 0 < n < MIN_N_INTERVAL else "")
                + "</p>")
    if run.kind == "bench transfer":
        body += [page.heading(lvl, f"{pre}-table1", "Table 1: the paper beside ours"), _table1(run)]
        paired, diff_rows = _paired(run, [m for m in (*PAIR_METRICS, "S_content", "E_style") if m in run.metric_names])
        if paired:
            body += [page.heading(lvl, f"{pre}-paired", "Paired differences"), paired]
        figs = _transfer_figures(run, diff_rows)
        if figs:
            body += [page.heading(lvl, f"{pre}-figures", "Figures"), figs]
        table, v = _item_table(page, run, pre, metrics=PAIR_METRICS,
                               methods=[m for m in run.methods if m != NO_TRANSFER], rank_metrics=("S_style", "E_content"))
        body += [page.heading(lvl, f"{pre}-pairs", "Pairs"), table]
        viewers.append(v)
        body += [page.heading(lvl, f"{pre}-metrics", "Every metric"), _all_metrics(run)]
    elif run.kind == "bench persona":
        body += [page.heading(lvl, f"{pre}-leaveout", "Leave-out (Tom Hanks Fig. 5)"), _leave_out_table(run)]
        paired, _ = _paired(run, [k for k in ("face_ssim", "mouth_ssim", "eyes_ssim") if k in run.metric_names])
        if paired:
            body += [page.heading(lvl, f"{pre}-paired", "Paired differences"), paired]
        sheets = "".join(_sheet(p, p.name) for p in run.figures)
        if sheets:
            body += [page.heading(lvl, f"{pre}-sheets", "Contact sheets"), sheets]
        table, v = _item_table(page, run, pre, metrics=("face_ssim", "mouth_ssim"), label_head="held-out photo",
                               rank_metrics=("mouth_ssim",), zooms=False)
        body += [page.heading(lvl, f"{pre}-targets", "Targets"), table]
        viewers.append(v)
    elif run.kind == "bench puppet":
        body += [page.heading(lvl, f"{pre}-summary", "Puppet runs: targets"), _puppet_summary(run)]
        worst = _worst_item(run)
        table, v = _item_table(page, run, pre, metrics=PUPPET_METRICS, label_head="run", zooms=False,
                               highlight=(lambda it: it is worst))
        body += [page.heading(lvl, f"{pre}-runs", "Runs"),
                 (f"<p>Worst run (highest fail score, the red row): <b>{_e(worst.label)}</b>.</p>" if worst else
                  "<p>Every run met every target.</p>"), table]
        viewers.append(v)
        sheets = "".join(_sheet(p, f"worst run {w.get('run', '')}: {', '.join(w.get('failed') or []) or 'no target failed'}")
                         for w, p in run.extra.get("worst_sheets", []))
        if sheets:
            body += [page.heading(lvl, f"{pre}-worst", "Worst runs' sheets"), sheets]
    else:
        body += [page.heading(lvl, f"{pre}-metrics", "Metrics"), _all_metrics(run).replace("<details>", "<details open>")]
        metrics = [k for k in KEY_METRICS if k in run.metric_names][:3] or _order(run.metric_names)[:3]
        table, v = _item_table(page, run, pre, metrics=metrics, label_head="item")
        body += [page.heading(lvl, f"{pre}-items", "Items"), table]
        viewers.append(v)
        figs = "".join(_sheet(p, p.name) for p in run.figures)
        if figs:
            body += [page.heading(lvl, f"{pre}-figures", "Figures"), figs]
    body += [page.heading(lvl, f"{pre}-settings", "Settings and provenance"), _settings_html(run), _provenance(run)]
    if run.tables:
        body.append("".join(f"<details><summary>{_e(name)}, as written by the run</summary>{_markdown_table(md)}"
                            "</details>" for name, md in run.tables.items()))
    files = [p for p in run.figures]
    if files:
        body.append("<p class='note'>Files: " + " · ".join(page.link(p, p.name) for p in files) + "</p>")
    return body, viewers


def build_report(runs: Sequence[Run], *, title: str | None = None, link_base=None) -> str:
    """The report page (HTML text) of ``runs``.

    Parameters
    ----------
    runs : sequence of Run
        Run folders read by :func:`facetex.report.load_runs`.
    title : str, optional
        Page title (default: the folders' names).
    link_base : path, optional
        The folder the page will be written to: links to the run folders' files are relative
        to it (absolute ``file:`` links without it).

    Returns
    -------
    str
        The HTML page.
    """
    from .. import __version__

    title = title or ("facetex report: " + ", ".join(r.name for r in runs))
    page = _Page(Path(link_base) if link_base is not None else None)
    body, viewers = [], []
    multi = len(runs) > 1
    for i, run in enumerate(runs):
        b, v = _run_sections(page, run, i, multi)
        body += b
        viewers += v
    if multi:
        body += [page.heading(2, "compare", "Comparison of the runs"), _comparison(runs)]
    skipped = list(dict.fromkeys(p for r in runs for p in r.skipped))
    head = [f"<h1>{_e(title)}</h1>",
            f"<p class='note'>facetex {_e(__version__)}, {len(runs)} run folder(s); everything, images included, is "
            "inside this file.</p>"]
    if skipped:
        head.append(f"<p class='note'>Skipped {len(skipped)} file(s) that are not regular files inside the run "
                    "folders (links, FIFOs, devices, or elsewhere): " + ", ".join(f"<code>{_e(p)}</code>" for p in
                                                                                    skipped[:50]) + "</p>")
    head.append(page.toc_html())
    viewer = ("<div id='viewer' role='dialog' aria-label='image viewer'><div class='bar'>"
              "<button id='viewer-prev'>← previous</button><button id='viewer-next'>next →</button>"
              "<button id='viewer-close'>close (Esc)</button><span id='viewer-caption'></span></div>"
              + "".join(viewers) + "</div>")
    return ("<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
            "<meta name='viewport' content='width=device-width, initial-scale=1'>"
            f"<title>{_e(title)}</title><style>{_CSS}</style></head><body>"
            + "\n".join(head + body) + viewer + f"<script>{_JS}</script></body></html>\n")
