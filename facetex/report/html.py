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

import json
from pathlib import Path
from typing import Sequence

from .._methods import NO_TRANSFER, method_title
from ._markup import MAX_IMAGE_ROWS, MIN_ZOOM_PX, THUMB_SIDE, ZOOM_REGIONS, _e, _fig_uri, _markdown_table, _Page
from ._page_assets import _CSS, _JS
from .bench_sections import PUPPET_METRICS, _leave_out_table, _puppet_summary, _sheet, _worst_item
from .compare import (
    KEY_METRICS,
    _fmt,
    _order,
    cell,
    compare_rows,
)
from .metric_info import PAIR_METRICS
from .runs import Run
from .transfer_sections import _all_metrics, _item_table, _paired, _table1, _transfer_figures

__all__ = ["build_report", "ZOOM_REGIONS", "THUMB_SIDE", "MAX_IMAGE_ROWS", "MIN_ZOOM_PX"]

_DEFAULTS = {"preset": "default", "seed": 0, "size": None, "device": "cpu", "iters": None}


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
