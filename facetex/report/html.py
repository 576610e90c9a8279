"""``facetex report``: one self-contained HTML page for one or more run folders.

Everything is inside the file (images as data URIs, CSS and a small script), so it can be
mailed or archived. Per run: settings (with what differs from the defaults), the run's own
tables, a metrics table with spread (mean ± std, 95 % CI) and the paper's values, a figure
of the per-item metrics with the paper's numbers as labelled reference marks, zoomable image
grids (click an image: it opens at 100 %; ←/→ or the buttons switch between content, style
and the methods of the same pair), face-crop zoom panels at native resolution, per-item
metrics and the provenance (sidecar) records. With two or more runs: a side-by-side
comparison of their metrics (the same as ``facetex compare``).

The page checks itself when opened with ``#selftest`` (used by the browser test): it
records script errors, verifies that every image decoded and that a click opens the viewer
at 100 %, and writes the result into ``<pre id="selftest-result">``.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from pathlib import Path
from typing import Sequence

import numpy as np

from ..io import read_regular
from .compare import compare_rows, cell, metric_summary, _fmt
from .runs import Run

__all__ = ["build_report"]

_MIME = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".webp": "image/webp",
         ".svg": "image/svg+xml"}
_DEFAULTS = {"preset": "default", "seed": 0, "size": None, "device": "cpu", "iters": None}


def _data_uri(data: bytes, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


def _file_uri(path: Path, *, max_side: int | None = None) -> str:
    """A data URI of an image file; browsers do not show TIFF, which is re-encoded as PNG (as
    is anything above ``max_side``)."""
    ext = path.suffix.lower()
    if ext in _MIME and max_side is None:
        return _data_uri(read_regular(path), _MIME[ext])
    from ..io import encode_image, read_image

    img = read_image(path)
    if max_side is not None and max(img.shape[:2]) > max_side:
        import cv2

        s = max_side / max(img.shape[:2])
        img = cv2.resize(img, (round(img.shape[1] * s), round(img.shape[0] * s)), interpolation=cv2.INTER_AREA)
    return _data_uri(encode_image("x.png", img), "image/png")


def _array_uri(img: np.ndarray) -> str:
    from ..io import encode_image

    return _data_uri(encode_image("x.png", img), "image/png")


def _fig_uri(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="svg", bbox_inches="tight", metadata={"Date": None})
    finally:
        plt.close(fig)
    return _data_uri(buf.getvalue(), "image/svg+xml")


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def _markdown_table(md: str) -> str:
    """The pipe tables and text lines of a run's Markdown file as HTML (headings, paragraphs)."""
    out, rows = [], []

    def flush():
        if not rows:
            return
        head, *body = rows
        body = [r for r in body if not all(set(c.strip()) <= set("-:") for c in r)]
        out.append("<table class='md'><thead><tr>" + "".join(f"<th>{_e(c)}</th>" for c in head) +
                   "</tr></thead><tbody>" + "".join("<tr>" + "".join(f"<td>{_e(c)}</td>" for c in r) + "</tr>"
                                                    for r in body) + "</tbody></table>")
        rows.clear()

    for line in md.splitlines():
        s = line.strip()
        if s.startswith("|") and s.endswith("|"):
            rows.append([c.strip().replace("\\|", "|") for c in s.strip("|").split(" | ")])
            continue
        flush()
        if s.startswith("#"):
            level = min(6, len(s) - len(s.lstrip("#")) + 2)
            out.append(f"<h{level}>{_e(s.lstrip('#').strip())}</h{level}>")
        elif s:
            out.append(f"<p>{_e(s)}</p>")
    flush()
    return "\n".join(out)


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


def _summary_table(run: Run) -> str:
    rows = metric_summary(run)
    if not rows:
        return "<p>No per-item metrics in this run.</p>"
    has_paper = any(r["paper"] is not None for r in rows)
    head = ["method", "metric", "n", "mean", "std", "95 % CI of the mean"] + (["paper (other data)"] if has_paper else [])
    body = []
    for r in rows:
        ci = "–" if not math.isfinite(r["ci95_half"]) else f"[{_fmt(r['ci95'][0])}, {_fmt(r['ci95'][1])}]"
        cells = [r["method"], r["metric"], r["n"], _fmt(r["mean"]), _fmt(r["std"], 2), ci]
        if has_paper:
            cells.append("–" if r["paper"] is None else _fmt(r["paper"]))
        body.append(cells)
    return ("<table class='metrics'><thead><tr>" + "".join(f"<th>{_e(h)}</th>" for h in head) + "</tr></thead><tbody>"
            + "".join("<tr>" + "".join(f"<td>{_e(c)}</td>" for c in b) + "</tr>" for b in body) + "</tbody></table>"
            + "<p class='note'>std: sample standard deviation over the items; CI: Student t. "
            + (_e(f"Paper values: {run.paper_source} — other data, shown as a reference.") if has_paper else "")
            + "</p>")


def _figure(run: Run) -> str:
    from .compare import KEY_METRICS
    from .figures import metrics_figure

    methods = run.methods
    metrics = [m for m in KEY_METRICS if m in run.metric_names][:6] or run.metric_names[:6]
    if not methods or not metrics:
        return ""
    series = {m: {k: run.values(m, k) for k in metrics} for m in methods}
    fig = metrics_figure(series, metrics, paper=run.paper or None, title=f"{run.name}: per-item metrics")
    return f"<figure><img class='figure' alt='metrics of {_e(run.name)}' src='{_fig_uri(fig)}'></figure>"


def _grid(run: Run, r_i: int) -> str:
    if not any(it.images for it in run.items):
        return ""
    parts = ["<div class='grid'>"]
    for k, it in enumerate(run.items):
        if not it.images:
            continue
        group = f"r{r_i}i{k}"
        parts.append(f"<div class='row'><div class='rowlabel'>{_e(it.label)}</div>")
        for label, path in it.images.items():
            uri = _file_uri(path)
            parts.append(f"<figure class='cell'><img class='thumb' loading='eager' data-group='{group}' "
                         f"data-label='{_e(label)}' alt='{_e(label)}: {_e(it.label)}' src='{uri}'>"
                         f"<figcaption>{_e(label)}</figcaption></figure>")
        parts.append("</div>")
    parts.append("</div><p class='note'>Click an image to see it at 100 %; ← → (or the buttons) switch between "
                 "the images of the same row, Esc closes.</p>")
    return "".join(parts)


def _zoom_panels(run: Run, limit: int = 6) -> str:
    """Face-crop and cheek zoom panels at native resolution of the first items."""
    from ..errors import FacetexError
    from ..io import read_image
    from ..landmarks import detect_face
    from .figures import face_box, skin_box, zoom_panel

    out = []
    for it in run.items[:limit]:
        if "content" not in it.images:
            continue
        try:
            content = read_image(it.images["content"])
            pc = detect_face(content).points68
        except FacetexError:
            continue
        fbox, sbox = face_box(content, pc), skin_box(pc, content.shape)
        crops_face, crops_skin = [], []
        for label, path in it.images.items():
            try:
                img = read_image(path)
            except FacetexError:
                continue
            if label == "style" or img.shape != content.shape:
                try:
                    ps = detect_face(img).points68
                except FacetexError:
                    continue
                crops_face.append((label, img, face_box(img, ps)))
                crops_skin.append((label, img, skin_box(ps, img.shape)))
            else:
                crops_face.append((label, img, fbox))
                crops_skin.append((label, img, sbox))
        if len(crops_face) < 2:
            continue
        out.append(f"<h4>{_e(it.label)}</h4>")
        for what, crops in (("face crop", crops_face), ("cheek", crops_skin)):
            panel = zoom_panel(crops)
            out.append(f"<figure><img class='zoom' alt='{_e(what)} zoom, {_e(it.label)}' "
                       f"src='{_array_uri(panel)}'><figcaption>{_e(what)} at native resolution "
                       f"(1 image px = 1 screen px at 100 %)</figcaption></figure>")
    return "".join(out)


def _items_table(run: Run) -> str:
    methods, metrics = run.methods, run.metric_names
    if not run.items or not metrics:
        return ""
    from .compare import KEY_METRICS

    metrics = [m for m in KEY_METRICS if m in metrics] + [m for m in metrics if m not in KEY_METRICS]
    head = "<tr><th>item</th><th>method</th>" + "".join(f"<th>{_e(m)}</th>" for m in metrics) + "</tr>"
    body = []
    for it in run.items:
        for m in methods:
            if m not in it.metrics:
                continue
            vals = it.metrics[m]
            body.append(f"<tr><td>{_e(it.label)}</td><td>{_e(m)}</td>" + "".join(
                f"<td>{_e(_fmt(vals.get(k)) if isinstance(vals.get(k), (int, float)) else '–')}</td>" for k in metrics)
                + "</tr>")
    return f"<details><summary>Per-item metrics ({len(body)} rows)</summary><table class='items'>{head}{''.join(body)}</table></details>"


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
        f"<tr><td>{_e(r['method'])}</td><td>{_e(r['metric'])}</td>" + "".join(f"<td>{_e(cell(c))}</td>" for c in r["runs"])
        + "".join(f"<td>{_e(_fmt(d))}</td>" for d in r["delta"][1:]) + "</tr>" for r in rows)
    legend = "".join(f"<li>[{i + 1}] <code>{_e(r.path)}</code> — {_e(r.kind)}, {len(r.items)} items</li>"
                     for i, r in enumerate(runs))
    from .compare import KEY_METRICS
    from .figures import metrics_figure

    fig_html = ""
    common = [m for m in KEY_METRICS if all(m in r.metric_names for r in runs)][:6]
    if common:
        series = {}
        for i, r in enumerate(runs):
            for m in r.methods:
                series[f"[{i + 1}] {m}"] = {k: r.values(m, k) for k in common}
        fig = metrics_figure(series, common, title="runs side by side")
        fig_html = f"<figure><img class='figure' alt='comparison' src='{_fig_uri(fig)}'></figure>"
    return (f"<ul>{legend}</ul><table class='compare'>{head}{body}</table>"
            "<p class='note'>mean ± sample std (n items); Δ: difference of the means from run [1].</p>" + fig_html)


_CSS = """
body{font:14px/1.45 system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:0 auto;max-width:1400px;padding:0 18px 60px;color:#222}
h1{font-size:24px}h2{border-bottom:2px solid #ddd;padding-bottom:4px;margin-top:36px}h3{margin-top:24px}
table{border-collapse:collapse;margin:8px 0 14px;font-size:13px}th,td{border:1px solid #ddd;padding:3px 7px;text-align:right}
th:first-child,td:first-child,th:nth-child(2),td:nth-child(2){text-align:left}
table.kv th{text-align:left;background:#f6f6f6}table.kv td{text-align:left;font-family:monospace}
tr.nondefault th,tr.nondefault td{background:#fff4d6}
thead th{background:#f0f0f0}.note{color:#666;font-size:12px}
.grid .row{display:flex;flex-wrap:wrap;align-items:flex-start;gap:8px;margin:10px 0;padding:6px;border:1px solid #eee}
.rowlabel{width:100%;font-weight:600}
.cell{margin:0;text-align:center}.cell img{width:180px;height:auto;cursor:zoom-in;border:1px solid #ccc;display:block}
.cell figcaption{font-size:12px}
img.figure{max-width:100%}img.zoom{max-width:100%;image-rendering:pixelated}
#viewer{display:none;position:fixed;inset:0;background:#141414;z-index:10;overflow:auto;color:#eee}
#viewer.open{display:block}
#viewer .bar{position:sticky;top:0;background:#111;padding:6px 10px;display:flex;gap:6px;align-items:center;flex-wrap:wrap}
#viewer button{background:#333;color:#eee;border:1px solid #555;padding:3px 10px;cursor:pointer;border-radius:3px}
#viewer button.on{background:#2a6df4;border-color:#2a6df4}
#viewer img{display:block;margin:10px auto;image-rendering:pixelated;max-width:none}
#viewer.fit img{max-width:98vw;max-height:88vh}
pre{background:#f7f7f7;padding:8px;overflow:auto;max-height:420px;font-size:12px}
code{background:#f3f3f3;padding:0 3px}
"""

_JS = r"""
(function(){
  var errors=[];
  window.addEventListener('error',function(e){errors.push(String(e.message||e));});
  var origError=console.error;console.error=function(){errors.push(Array.prototype.join.call(arguments,' '));origError.apply(console,arguments);};
  var viewer=document.getElementById('viewer'),vimg=document.getElementById('viewer-img'),
      vbtns=document.getElementById('viewer-buttons'),vcap=document.getElementById('viewer-caption');
  var current=null,list=[];
  function show(i){
    current=i;var t=list[i];vimg.src=t.src;vimg.alt=t.alt;vcap.textContent=t.alt+' — '+(viewer.classList.contains('fit')?'fitted':'100 %');
    Array.prototype.forEach.call(vbtns.children,function(b,k){b.className=k===i?'on':'';});
  }
  function open(thumb){
    list=Array.prototype.slice.call(document.querySelectorAll('img.thumb[data-group="'+thumb.dataset.group+'"]'));
    vbtns.innerHTML='';
    list.forEach(function(t,k){var b=document.createElement('button');b.textContent=t.dataset.label;
      b.addEventListener('click',function(){show(k);});vbtns.appendChild(b);});
    viewer.classList.add('open');viewer.classList.remove('fit');show(list.indexOf(thumb));
  }
  function close(){viewer.classList.remove('open');current=null;}
  document.addEventListener('click',function(e){var t=e.target;if(t&&t.classList&&t.classList.contains('thumb')){open(t);}});
  document.getElementById('viewer-close').addEventListener('click',close);
  document.getElementById('viewer-fit').addEventListener('click',function(){viewer.classList.toggle('fit');if(current!==null)show(current);});
  document.addEventListener('keydown',function(e){
    if(current===null)return;
    if(e.key==='Escape')close();
    else if(e.key==='ArrowRight')show((current+1)%list.length);
    else if(e.key==='ArrowLeft')show((current-1+list.length)%list.length);
  });
  function selftest(){
    var out=document.getElementById('selftest-result');
    var imgs=Array.prototype.slice.call(document.images).filter(function(i){return i.id!=='viewer-img';});
    var decoded=imgs.filter(function(i){return i.complete&&i.naturalWidth>0;}).length;
    var res={images:imgs.length,decoded:decoded,errors:errors,viewer:null};
    var thumb=document.querySelector('img.thumb');
    if(thumb){
      thumb.click();
      var done=function(){
        res.viewer={open:viewer.classList.contains('open'),natural:[vimg.naturalWidth,vimg.naturalHeight],
                    shown:[vimg.clientWidth,vimg.clientHeight],buttons:vbtns.children.length,
                    same_source:vimg.src===thumb.src};
        if(location.hash!=='#selftest-zoom')close();
        out.textContent=JSON.stringify(res);
      };
      if(vimg.complete&&vimg.naturalWidth>0)done();else vimg.addEventListener('load',done);
    } else { out.textContent=JSON.stringify(res); }
  }
  if(location.hash.indexOf('#selftest')===0){
    if(document.readyState==='complete')selftest();else window.addEventListener('load',selftest);
  }
})();
"""


def build_report(runs: Sequence[Run], *, title: str | None = None) -> str:
    """The report page (HTML text) of ``runs``."""
    from .. import __version__

    title = title or ("facetex report: " + ", ".join(r.name for r in runs))
    body = [f"<h1>{_e(title)}</h1>",
            f"<p class='note'>Made by facetex {_e(__version__)} from {len(runs)} run folder(s). "
            "Everything (images included) is inside this file.</p>"]
    skipped = list(dict.fromkeys(p for r in runs for p in r.skipped))
    if skipped:
        body.append(f"<p class='note'>Skipped {len(skipped)} file(s) that are not regular files inside the run "
                    "folders (links, FIFOs, devices, or elsewhere): " + ", ".join(f"<code>{_e(p)}</code>" for p in
                                                                                    skipped[:50]) + "</p>")
    if len(runs) > 1:
        body += ["<h2 id='compare'>Comparison of the runs</h2>", _comparison(runs)]
    for i, run in enumerate(runs):
        body.append(f"<h2 id='run{i + 1}'>[{i + 1}] {_e(run.name)} <small>({_e(run.kind)}, {len(run.items)} items)"
                    "</small></h2>")
        body.append(f"<p><code>{_e(run.path)}</code></p>")
        body += ["<h3>Settings</h3>", _settings_html(run)]
        body += ["<h3>Metrics (mean, spread, paper)</h3>", _summary_table(run), _figure(run)]
        for name, md in run.tables.items():
            body += [f"<h3>{_e(name)} (as written by the run)</h3>", _markdown_table(md)]
        grid = _grid(run, i)
        if grid:
            body += ["<h3>Images (click to compare at 100 %)</h3>", grid]
        zooms = _zoom_panels(run)
        if zooms:
            body += ["<h3>Zoom panels at native resolution</h3>", zooms]
        for fig in run.figures:
            body.append(f"<figure><img class='figure' alt='{_e(fig.name)}' src='{_file_uri(fig)}'>"
                        f"<figcaption>{_e(fig.name)}</figcaption></figure>")
        body += ["<h3>Per-item metrics</h3>", _items_table(run) or "<p>–</p>"]
        body += ["<h3>Provenance</h3>", _provenance(run)]
    viewer = ("<div id='viewer' role='dialog' aria-label='image viewer'><div class='bar'>"
              "<span id='viewer-buttons'></span><button id='viewer-fit'>fit / 100 %</button>"
              "<button id='viewer-close'>close (Esc)</button><span id='viewer-caption'></span></div>"
              "<img id='viewer-img' alt=''></div>")
    return ("<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
            "<meta name='viewport' content='width=device-width, initial-scale=1'>"
            f"<title>{_e(title)}</title><style>{_CSS}</style></head><body>"
            + "\n".join(body) + viewer + "<pre id='selftest-result' hidden></pre>"
            + f"<script>{_JS}</script></body></html>\n")
