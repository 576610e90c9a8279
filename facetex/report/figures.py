"""Figures for papers and reports: metric plots with spread and the paper's reference marks,
and face-crop zoom panels at native resolution.

Metric figures are matplotlib (PNG for screens, SVG and PDF for papers: use
:func:`facetex.bench._common.write_figure_formats`). Zoom panels are numpy images: crops of
the same face region of every image, side by side, *not resampled*, so texture is seen as
it is in the files.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

__all__ = ["face_box", "skin_box", "zoom_panel", "metrics_figure", "differences_figure", "METRIC_LABELS"]

#: axis labels of the metrics facetex writes (others are shown by their key)
METRIC_LABELS = {
    "E_content": "E(xt, xc): landmark error to the content (px², lower = identity kept)",
    "E_style": "E(xt, xs): landmark error to the style (px²)",
    "S_content": "S(xt, xc): texture similarity to the content",
    "S_style": "S(xt, xs): texture similarity to the style (higher = more texture moved)",
    "identity_content": "identity distance to the content (< 0.6 = same person)",
    "identity_style": "identity distance to the style",
    "time_s": "wall time per image (s)",
}


def face_box(image: np.ndarray, points68=None, *, margin: float = 0.12) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of the face (jaw, brows, forehead) with a margin, in ``image``'s
    pixels; the image's centre square when no face is found."""
    from ..errors import NoFaceError

    h, w = image.shape[:2]
    if points68 is None:
        from ..landmarks import detect_face

        try:
            points68 = detect_face(image).points68
        except NoFaceError:
            s = min(h, w) // 2
            return (w - s) // 2, (h - s) // 2, (w + s) // 2, (h + s) // 2
    from ..transfer import face_crop_box

    return tuple(int(v) for v in face_crop_box(points68, image.shape, margin))


def skin_box(points68, shape, *, side: float = 0.3) -> tuple[int, int, int, int]:
    """A square on the left cheek (the image's left), ``side`` × the face width, where skin
    texture is seen best: centred between the jaw points 2-4, the nose wing 31 and the mouth
    corner 48."""
    p = np.asarray(points68, np.float64)
    width = float(np.linalg.norm(p[16] - p[0]))
    c = (p[[2, 3, 4]].mean(0) + p[31] + p[48]) / 3.0
    half = max(8, int(round(side * width / 2)))
    h, w = shape[:2]
    x0, y0 = int(round(c[0])) - half, int(round(c[1])) - half
    x0, y0 = min(max(0, x0), max(0, w - 2 * half)), min(max(0, y0), max(0, h - 2 * half))
    return x0, y0, min(w, x0 + 2 * half), min(h, y0 + 2 * half)


def zoom_panel(crops: Sequence[tuple[str, np.ndarray, Sequence[int]]], *, gap: int = 6,
               label_height: int = 24) -> np.ndarray:
    """Crops of several images side by side at native resolution (no resampling).

    Parameters
    ----------
    crops : sequence of (label, image, box)
        ``image`` float [0, 1] or uint8 RGB; ``box`` (x0, y0, x1, y1) in its pixels. Crops
        of different sizes are top-aligned on a white background.
    gap : int
        White space between crops (px).
    label_height : int
        Height of the label band above each crop (px).

    Returns
    -------
    numpy.ndarray
        uint8 RGB panel.

    Examples
    --------
    >>> import numpy as np
    >>> a = np.zeros((100, 100, 3), np.uint8)
    >>> zoom_panel([("a", a, (10, 10, 60, 40)), ("b", a, (0, 0, 20, 20))]).shape
    (54, 76, 3)
    """
    import cv2

    from ..errors import BadInputError
    from ..io import to_uint8

    if not crops:
        raise BadInputError("zoom_panel needs at least one crop")
    tiles = []
    for label, image, box in crops:
        img = to_uint8(np.asarray(image))
        if img.ndim == 2:
            img = np.repeat(img[..., None], 3, axis=2)
        x0, y0, x1, y1 = (int(v) for v in box)
        h, w = img.shape[:2]
        x0, y0, x1, y1 = max(0, x0), max(0, y0), min(w, x1), min(h, y1)
        if x1 <= x0 or y1 <= y0:
            raise BadInputError(f"zoom box {tuple(box)} lies outside the {w}x{h} image {label!r}")
        tiles.append((str(label), img[y0:y1, x0:x1, :3]))
    H = label_height + max(t.shape[0] for _, t in tiles)
    W = sum(t.shape[1] for _, t in tiles) + gap * (len(tiles) - 1)
    out = np.full((H, W, 3), 255, np.uint8)
    x = 0
    for label, t in tiles:
        out[label_height:label_height + t.shape[0], x:x + t.shape[1]] = t
        scale = 0.45
        while scale > 0.25 and cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] > t.shape[1] - 4:
            scale *= 0.9
        cv2.putText(out, label, (x + 2, label_height - 7), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1,
                    cv2.LINE_AA)
        x += t.shape[1] + gap
    return out


def _plain(text) -> str:
    """``text`` shown as it is: a ``$`` would start matplotlib's mathtext (method and metric
    names come from run folders, and ``$\\foo$`` makes savefig raise)."""
    return str(text).replace("$", r"\$")


def _interval_bar(ax, x, values, metric, colour):
    """The mean of ``values`` at ``x`` with its bootstrap 95 % interval inside the metric's range
    (the mean alone when there are too few values for an interval)."""
    from .._stats import bootstrap_mean
    from .metric_info import metric_info

    b = bootstrap_mean(values, bounds=metric_info(metric).bounds)
    if b["n"] == 0:
        return
    if math.isfinite(b["lo"]):
        ax.errorbar([x], [b["mean"]], yerr=[[b["mean"] - b["lo"]], [b["hi"] - b["mean"]]], fmt="o", color=colour,
                    capsize=4, ms=6, zorder=3)
    else:
        ax.plot([x], [b["mean"]], marker="_", ms=16, mew=2.5, color=colour, zorder=3)


#: at most this many dots per group and panel (evenly spaced items; means and intervals use them all):
#: an SVG of 30 000 dots per panel is hundreds of MB (issue 23)
MAX_DOTS = 2000


def _dots(values: np.ndarray) -> np.ndarray:
    """``values``, or :data:`MAX_DOTS` of them evenly spaced when there are more."""
    if values.size <= MAX_DOTS:
        return values
    return values[np.linspace(0, values.size - 1, MAX_DOTS).round().astype(int)]


def metrics_figure(series: Mapping[str, Mapping[str, Sequence[float]]], metrics: Sequence[str], *,
                   paper: Mapping[str, Mapping[str, float]] | None = None, paper_label: str = "paper (other data)",
                   title: str = "", colours: Mapping[str, str] | None = None,
                   titles: Mapping[str, str] | None = None):
    """One panel per metric: every item as a dot, the mean with its bootstrap 95 % interval
    (inside the metric's range; no interval when there are too few items, see
    :func:`facetex._stats.bootstrap_mean`) per group; the paper's values as labelled
    reference marks.

    Parameters
    ----------
    series : mapping
        group label (e.g. ``"FaceTex"`` or ``"run A: FaceTex"``) -> metric -> per-item values.
    metrics : sequence of str
        Metric keys to draw (one panel each).
    paper : mapping, optional
        group label -> metric -> the paper's value, drawn as a hollow diamond with
        ``paper_label``: numbers from other data, a reference, not a target.
    title : str
        Figure title.
    colours : mapping, optional
        group label -> matplotlib colour.
    titles : mapping, optional
        metric -> panel title (default :data:`METRIC_LABELS`, else the key).

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = list(series)
    n = len(metrics)
    cols = min(3, max(1, n))
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.4 * rows + 0.6), squeeze=False)
    palette = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    colours = dict(colours or {})
    rng = np.random.default_rng(0)
    for k, metric in enumerate(metrics):
        ax = axes[k // cols][k % cols]
        for g_i, g in enumerate(groups):
            col = colours.get(g, palette[g_i % len(palette)])
            vals = np.array([v for v in series[g].get(metric, []) if v is not None], float)
            vals = vals[np.isfinite(vals)]
            if vals.size:
                dots = _dots(vals)
                jitter = rng.uniform(-0.12, 0.12, dots.size)
                ax.scatter(np.full(dots.size, g_i) + jitter, dots, s=16, color=col, alpha=0.55, zorder=2)
                _interval_bar(ax, g_i + 0.3, vals, metric, col)
            ref = (paper or {}).get(g, {}).get(metric)
            if ref is not None and math.isfinite(ref):
                ax.scatter([g_i + 0.3], [ref], marker="D", s=42, facecolors="none", edgecolors="black",
                           linewidths=1.2, zorder=4, label=paper_label if g_i == 0 or k == 0 else None)
                ax.annotate("paper", (g_i + 0.3, ref), xytext=(6, 0), textcoords="offset points", fontsize=7,
                            va="center")
        ax.set_xticks(range(len(groups)))
        ax.set_xticklabels([_plain(g) for g in groups], rotation=20 if len(groups) > 3 else 0,
                           ha="right" if len(groups) > 3 else "center", fontsize=8)
        ax.set_title(_plain((titles or {}).get(metric) or METRIC_LABELS.get(metric, metric)), fontsize=8)
        ax.grid(axis="y", alpha=0.3)
    for k in range(n, rows * cols):
        axes[k // cols][k % cols].axis("off")
    handles = [plt.Line2D([], [], marker="o", ls="", color="grey", alpha=0.55, label="one item (pair)"),
               plt.Line2D([], [], marker="o", ls="-", color="grey", label="mean, bootstrap 95 % interval"),
               plt.Line2D([], [], marker="_", ls="", ms=12, mew=2.5, color="grey", label="mean (too few items for an interval)")]
    if paper:
        handles.append(plt.Line2D([], [], marker="D", ls="", mfc="none", mec="black",
                                  label=f"{paper_label}: a reference, not comparable data"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8, frameon=False)
    if title:
        fig.suptitle(_plain(title), fontsize=10)
    fig.tight_layout(rect=(0, 0.07, 1, 0.95 if title else 1))
    return fig


def differences_figure(rows: Sequence[Mapping], metrics: Sequence[str], *, labels: Mapping[tuple, str],
                       titles: Mapping[str, str] | None = None, title: str = ""):
    """Paired differences: one panel per metric, one column per method pair ``a − b``: each
    item's difference as a dot, their mean with its bootstrap 95 % interval, and 0 as a line.

    Parameters
    ----------
    rows : sequence of mapping
        :func:`facetex.report.compare.paired_differences` results.
    metrics : sequence of str
        Metrics to draw (one panel each).
    labels : mapping
        ``(a, b)`` -> the column's label (e.g. ``"FaceTex − MRF-CNN"``).
    titles : mapping, optional
        metric -> panel title.
    title : str
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pairs = list(dict.fromkeys((r["a"], r["b"]) for r in rows))
    n = max(1, len(metrics))
    fig, axes = plt.subplots(1, n, figsize=(max(4.2, 0.9 * len(pairs) + 1.6) * n, 3.8), squeeze=False)
    rng = np.random.default_rng(0)
    for k, metric in enumerate(metrics):
        ax = axes[0][k]
        ax.axhline(0, color="black", lw=0.8, zorder=1)
        for j, ab in enumerate(pairs):
            r = next((r for r in rows if (r["a"], r["b"]) == ab and r["metric"] == metric), None)
            if r is None or not r["diffs"]:
                continue
            d = _dots(np.asarray(r["diffs"], float))
            ax.scatter(np.full(d.size, j) + rng.uniform(-0.12, 0.12, d.size), d, s=14, color="tab:blue", alpha=0.5,
                       zorder=2)
            if math.isfinite(r["lo"]):
                ax.errorbar([j + 0.3], [r["mean"]], yerr=[[r["mean"] - r["lo"]], [r["hi"] - r["mean"]]], fmt="o",
                            color="black", capsize=4, ms=5, zorder=3)
            else:  # too few items for an interval: the mean alone
                ax.plot([j + 0.3], [r["mean"]], marker="_", ms=16, mew=2.5, color="black", zorder=3)
        ax.set_xticks(range(len(pairs)))
        ax.set_xticklabels([_plain(labels.get(ab, f"{ab[0]} − {ab[1]}")) for ab in pairs], rotation=30, ha="right",
                           fontsize=7)
        ax.set_title(_plain((titles or {}).get(metric, metric)), fontsize=8)
        ax.grid(axis="y", alpha=0.3)
    if title:
        fig.suptitle(_plain(title), fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.93 if title else 1))
    return fig
