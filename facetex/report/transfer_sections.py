"""The transfer bench's sections of the report (:mod:`facetex.report.html`, 1-5): Table 1 beside the
paper, paired differences, figures, and the sortable per-item table with its viewer and native-resolution
zooms (also used by the persona and puppet sections)."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .._methods import METHOD_COLOURS, NO_TRANSFER, method_title
from ._markup import (
    CROP_QUALITY,
    MAX_IMAGE_ROWS,
    MIN_ZOOM_PX,
    THUMB_QUALITY,
    THUMB_SIDE,
    ZOOM_REGIONS,
    _e,
    _fig_uri,
    _interval_text,
    _num,
    _Page,
    _signed,
    _webp,
)
from .compare import (
    _fmt,
    best_counts,
    interval_summary,
    method_pairs,
    paired_differences,
)
from .metric_info import PAIR_METRICS, TABLE1_METRICS, metric_info
from .runs import Item, Run

__all__ = [
]


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
                cells.append(f"<td class='paper'>{_e(format(ref, '.10g')) if ref is not None else '–'}</td>")
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


