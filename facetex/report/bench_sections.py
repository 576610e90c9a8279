"""The persona leave-out and puppet bench sections of the report (:mod:`facetex.report.html`)."""

from __future__ import annotations

import math
from pathlib import Path

from ._markup import SHEET_QUALITY, _e, _interval_text, _signed, _webp
from .compare import (
    _fmt,
    interval_summary,
    paired_differences,
)
from .metric_info import metric_info
from .runs import Run
from .transfer_sections import _read

__all__ = [
    "PERSONA_METRICS",
    "PUPPET_METRICS",
]


# ---------------------------------------------------------------- persona and puppet benches

PERSONA_METRICS = ("face_ssim", "mouth_ssim", "eyes_ssim", "face_grad_corr", "face_colour_diff")
PUPPET_METRICS = ("mouth_slope", "mouth_r", "cheek_de", "eye_ratio", "sharp", "sharp_half", "id_closer", "id_puppet",
                  "flicker", "fps", "fail_score")


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


