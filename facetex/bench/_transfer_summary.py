"""The summary files of ``facetex bench transfer``: Table 1 (Markdown and CSV rows, the
issue-22 measures per pair), the scatter plot of Figure 4, the grid of Figure 3 and the zoom
sheets."""


from __future__ import annotations

from pathlib import Path

import numpy as np

from .._methods import METHOD_COLOURS, METHOD_TITLES
from ..io import read_image, write_image
from ._common import (
    ResultStore,
    markdown_table,
    mean_finite,
    write_figure_formats,
    write_grid,
)
from ._transfer_spec import (
    GRID_ORDER,
    METHODS,
    METRIC_KEYS,
    PAIR_COLUMNS,
    PAPER_COLUMNS,
    PAPER_TABLE1,
    SAME_PERSON,
    TABLE_COLUMNS,
    ZOOM_ROWS,
)


def _summary_rows(records: dict, pairs, methods) -> list[dict]:
    rows = []
    for method in methods:
        recs = [records[(c, s, method)] for c, s in pairs if (c, s, method) in records]
        row = {"method": METHOD_TITLES[method], "method_id": method, "n_pairs": len(recs)}
        for k in METRIC_KEYS:
            row[k] = mean_finite(r["metrics"][k] for r in recs)
        row["same_identity"] = sum(1 for r in recs if r["metrics"]["identity_content"] < SAME_PERSON)
        row["time_s"] = mean_finite(r["wall_s"] for r in recs)
        row["cpu_s"] = mean_finite(r.get("cpu_s", float("nan")) for r in recs)
        row["prewarp_folds"] = int(sum(int(r.get("prewarp_folds") or 0) for r in recs))
        rows.append(row)
    return rows


def _pair_rows(records: dict, pairs, methods) -> list[dict]:
    """One row per (pair, method) with its metrics, worst low-frequency ΔE first."""
    rows = []
    for m in methods:
        for c, s in pairs:
            r = records.get((c, s, m))
            if r is None:
                continue
            met = dict(r["metrics"])
            for k in ("marks_content", "marks_style"):
                met[k] = int(met[k]) if np.isfinite(met.get(k, float("nan"))) else -1
            rows.append({"pair": f"{c} ← {s}", "method": METHOD_TITLES[m], **met, "time_s": r["wall_s"]})
    key = lambda r: -r["lowfreq_dE"] if np.isfinite(r.get("lowfreq_dE", float("nan"))) else 0.0  # noqa: E731
    return sorted(rows, key=key)


def _table_markdown(rows, settings, pair_rows=()) -> str:
    paper = [{"method": f"{METHOD_TITLES[m]} (paper)", **PAPER_TABLE1[m]} for m in METHODS]
    return "\n".join([
        "# FaceTex Table 1 — facial style transfer benchmark",
        "",
        f"{settings['n_pairs']} content/style pairs of different people from `{settings['data']}` "
        f"(seed {settings['seed']}, preset `{settings['preset']}`). Means over the pairs. "
        "E = mean squared landmark distance on the 66 FaceTex landmarks at 1000 px (px²; RMS in px "
        "beside it), S = Eq. 8 correlation of forehead and cheek patches, id = dlib face-descriptor "
        f"distance (< {SAME_PERSON}: same person), time = wall-clock seconds per output image. "
        "S gain = S(xt,xs) − S(xc,xs); detail = std (0–255) of luminance minus its σ = 2 px blur in the "
        "three skin patches at native resolution, detail ratio = detail(output) / detail(style aligned onto "
        "the content); protected Δ = mean |Δ| (0–255) over eyes, brows and lips; background Δ = mean |Δ| "
        "outside the face; folds = pre-warp pixels of the face where the map folds (all pairs). "
        "\"no transfer\" scores the content itself as the output. "
        "Issue 22: LF ΔE = ΔE76 (CIELAB) of the content's skin between output and content, both blurred at "
        "0.1 × the eye distance over the skin only (mean; max = worst of forehead and cheek patches); hair coh "
        "= structure-tensor coherence of the change image on the forehead skin (oriented strands: higher; "
        "style = what pasting the aligned style would give); specks = dark specks per 1000 px on the upper "
        "lip and chin, stubble moved = (output − content) / (style − content); coverage = fraction of the "
        "content's skin that changed (|Δ| blurred at 2 px > 1/255); detail moved = fraction of the way the "
        "σ = 2 px high-pass moved from the content's level to the style's own (cheeks: where the style is "
        "rougher; (skin): the same over the patches' skin pixels only, the style's without its moustache, "
        "stubble, hair or shine, which the whole cheek patch also measures); marks kept / arrived = the content's blobs (LoG) found again in the output / the style's "
        "that appear there. CPU s = process CPU time per image (the machine may be shared).",
        "",
        markdown_table(TABLE_COLUMNS, rows),
        *(["## Per pair, worst low-frequency ΔE first", "", markdown_table(PAIR_COLUMNS, list(pair_rows))]
          if pair_rows else []),
        "## Paper (Kaur, Zhang & Dana 2017, Table 1; head portraits of Shih et al., 5 pairs)",
        "",
        markdown_table(PAPER_COLUMNS, paper),
    ])


def _write_scatter(path, records, pairs, methods) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.8))
    panels = (("E_content", "E_style", "(a) landmark error (px² at 1000 px)", "E(xt, xc)", "E(xt, xs)"),
              ("S_content", "S_style", "(b) texture similarity", "S(xt, xc)", "S(xt, xs)"))
    for ax, (kx, ky, title, xl, yl) in zip(axes, panels):
        for m in methods:
            pts = np.array([[records[(c, s, m)]["metrics"][kx], records[(c, s, m)]["metrics"][ky]]
                            for c, s in pairs if (c, s, m) in records], dtype=float).reshape(-1, 2)
            ax.scatter(pts[:, 0], pts[:, 1], color=METHOD_COLOURS[m], label=METHOD_TITLES[m], s=36)
            ref = PAPER_TABLE1[m]
            ax.scatter([ref[kx]], [ref[ky]], color=METHOD_COLOURS[m], marker="x", s=70,
                       label=f"{METHOD_TITLES[m]} (paper mean)")
        ax.set_title(title)
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("FaceTex Figure 4: per-pair metrics (dots), paper means (crosses)")
    return write_figure_formats(Path(path).with_suffix(""), fig)[0]  # .png, and .svg + .pdf for papers


def _write_pair_zoom(out: Path, c: str, s: str, paths, methods, records, load) -> Path | None:
    """``zoom/<c>__<s>.png``: forehead, cheek and chin crops at native resolution."""
    from ._zoom import zoom_sheet

    target = out / "zoom" / f"{ResultStore.key(c, s)}.png"
    d = load()
    cols = [("content", d["content"])]
    pre = out / "images" / f"{ResultStore.key(c, s, 'prewarp')}.png"
    cols.append(("pre-warped style", read_image(pre) if pre.is_file() else d["aligned"]))
    for m in methods:
        img = out / "images" / f"{ResultStore.key(c, s, m)}.png"
        if (c, s, m) in records and img.is_file():
            cols.append((METHOD_TITLES[m], read_image(img)))
    sheet = zoom_sheet(cols, d["points_c"], regions=ZOOM_ROWS, title=f"content {c}, style {s} (2x, nearest)")
    target.parent.mkdir(exist_ok=True)
    return write_image(target, sheet, overwrite=True)


def _write_zoom(path: Path, out: Path, pairs) -> Path | None:
    """All pairs' zoom sheets stacked into one image."""
    sheets = [read_image(p) for c, s in pairs if (p := out / "zoom" / f"{ResultStore.key(c, s)}.png").is_file()]
    if not sheets:
        return None
    w = max(x.shape[1] for x in sheets)
    sheets = [np.pad(x, ((0, 8), (0, w - x.shape[1]), (0, 0)), constant_values=1.0) for x in sheets]
    return write_image(path, np.concatenate(sheets, 0), overwrite=True)


def _write_grid(path, out, pairs, paths, methods, records) -> Path:
    cols = [m for m in GRID_ORDER if m in methods]
    rows, labels = [], []
    for c, s in pairs:
        row = [read_image(paths[s]), read_image(paths[c])]
        for m in cols:
            img = out / "images" / f"{ResultStore.key(c, s, m)}.png"
            row.append(read_image(img) if (c, s, m) in records and img.is_file() else None)
        rows.append(row)
        labels.append([f"style {s}", f"content {c}"] + [None] * len(cols))
    titles = ["style", "content"] + [METHOD_TITLES[m] for m in cols]
    return write_grid(path, rows, col_titles=titles, cell_labels=labels, cell=256)
