"""``facetex bench transfer``: the facial style transfer benchmark of FaceTex §3.1.

Content/style pairs of different people are drawn from a folder of ``NNN_neutral.jpg``
portraits; every method (Neural Style = "gatys", MRF-CNN = "mrf", FaceTex) runs on every
pair, each output is scored against its content and style images with
:func:`facetex.metrics.transfer_metrics`, and the run is summarised as

- ``table.md`` / ``table.csv`` — Table 1 (means per method, plus identity distances and
  wall time; the paper's own values as a reference block in the Markdown);
- ``grid.png`` — Figure 3 (style, content, then the methods in Table 1's order per pair);
- ``scatter.png`` — Figure 4 ((a) landmark errors, (b) texture similarities per pair);
- ``results.json`` — every number per pair and method, and the settings (``"bench": "transfer"``,
  as in the other benches' ``results.json``);
- ``zoom.png`` (and ``zoom/<content>__<style>.png``) — forehead, cheek and chin crops at
  native resolution of the content, the pre-warped style and every output;
- ``images/<content>__<style>__prewarp.png`` — the pre-warped style the optimiser got.

Pairs are drawn by a seeded hash (:func:`facetex.bench._common.select_pairs`) or taken from
an explicit list (``pair_list``; :data:`ISSUE22_PAIRS` is the documented one of issue 22:
styles with a fringe, with stubble or a beard, with shiny skin, and pairs that differ in skin
tone and sex). ``table.md`` also lists the issue-22 measures per pair, worst first.

Besides the methods, a "no transfer" row scores the content itself as the output: a
metric that moves less than its distance from that row has shown nothing.

Each (pair, method) is stored as ``images/<content>__<style>__<method>.png`` (+ ``.json``
info) and ``results/<content>__<style>__<method>.json``; the result file is written last
and atomically, so an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from .._methods import METHOD_COLOURS, METHOD_TITLES, NO_TRANSFER, TRANSFER_METHODS
from ..errors import BadInputError, NoFaceError, OutputError
from ..io import read_image, to_uint8, write_image, write_json
from ._common import (Column, ResultStore, check_out_dir, csv_table, list_portraits, markdown_table,
                      json_safe, mean_finite, no_image_data, select_pairs, versions, write_figure_formats, write_grid,
                      write_text)

__all__ = ["METHODS", "METHOD_TITLES", "METHOD_COLOURS", "PAPER_TABLE1", "PRESETS",
           "run_bench_transfer", "register_bench", "run"]

DATA_SUBFOLDER = "frl-london"  # inside --data / $FACETEX_DATA (or --data is this folder itself)
METHODS = TRANSFER_METHODS  # one name and one order everywhere: facetex._methods
NONE = NO_TRANSFER  # the content scored as the output ("doing nothing")
PRESETS = ("default", "paper", "preview")
# Figure 3 shows MRF-CNN, FaceTex, Neural Style; the grid uses Table 1's order like every other table
# and page (issue 25: one order for the methods everywhere)
GRID_ORDER = METHODS
ZOOM_ROWS = ("forehead", "left cheek", "upper lip", "chin")  # where hair, shine and stubble show
SAME_PERSON = 0.6  # dlib's same-person threshold for the identity distance

# FaceTex Table 1 (Kaur, Zhang & Dana 2017): means over the five pairs of Figure 3
PAPER_TABLE1 = {
    "gatys": {"E_content": 22.61, "E_style": 369.39, "S_content": 0.89, "S_style": 0.47},
    "mrf": {"E_content": 106.17, "E_style": 191.47, "S_content": 0.70, "S_style": 0.68},
    "facetex": {"E_content": 37.93, "E_style": 295.93, "S_content": 0.76, "S_style": 0.55},
}
METRIC_KEYS = ("E_content", "E_style", "E_content_rms_px", "E_style_rms_px", "S_content", "S_style",
               "identity_content", "identity_style", "S_style_none", "S_style_gain", "detail_output",
               "detail_content", "detail_style", "detail_ratio", "protected_change", "background_change",
               "lowfreq_dE", "lowfreq_dE_max_region", "hair_leakage", "hair_leakage_style", "stubble_output",
               "stubble_content", "stubble_style", "stubble_moved", "coverage", "detail_moved",
               "detail_moved_cheeks", "detail_moved_cheeks_skin", "marks_content", "marks_kept", "marks_style", "marks_arrived")

# Issue 22's pairs (content, style) of FRL London neutral portraits, chosen by looking at them:
# the style has a fringe (F), stubble or a beard (B), shiny skin (S); the two differ in skin
# tone (T) and/or sex (X). The first 10 are the quick set used while iterating.
ISSUE22_PAIRS = (
    ("083", "037"),  # B X: pale young woman <- full-bearded man
    ("010", "003"),  # F: woman <- woman with a heavy fringe
    ("081", "043"),  # S T X: pale blonde woman <- dark-skinned man, shiny forehead
    ("025", "022"),  # B T X: dark-skinned woman <- pale man with a goatee and stubble
    ("087", "067"),  # F X: East Asian woman <- man with a long fringe
    ("063", "061"),  # S T: pale man <- dark-skinned man with shiny skin
    ("090", "092"),  # B X: woman <- bearded man
    ("042", "003"),  # F T X: dark-skinned man <- pale woman with a fringe
    ("030", "021"),  # S X: South-East Asian woman <- bald man, shiny head and forehead
    ("019", "004"),  # B X: young woman <- man with stubble
    ("009", "033"),  # B X: woman <- man with heavy stubble
    ("018", "045"),  # F: man <- man with a fringe
    ("097", "081"),  # F: woman <- woman with a side fringe
    ("006", "042"),  # S X: dark-skinned woman <- dark-skinned man, shiny skin
    ("061", "083"),  # T X: dark-skinned man <- pale woman
    ("062", "009"),  # T: dark-skinned woman <- pale woman
    ("002", "070"),  # B X: woman <- man with stubble
    ("034", "008"),  # T X: East Asian woman <- South Asian man
    ("068", "096"),  # T: pale man <- dark-skinned man
    ("044", "039"),  # X: freckled man <- woman
    ("038", "014"),  # spotted skin woman <- smooth-skinned woman (marks)
    ("004", "005"),  # B: the project's usual pair (stubbled man <- East Asian man)
)
PAIR_LISTS = {"issue22": ISSUE22_PAIRS}

TABLE_COLUMNS = (
    Column("method", "method"),
    Column("n_pairs", "pairs", "d"),
    Column("E_content", "E(xt,xc)", ".2f"),
    Column("E_style", "E(xt,xs)", ".2f"),
    Column("E_content_rms_px", "RMS(xt,xc) px", ".2f"),
    Column("E_style_rms_px", "RMS(xt,xs) px", ".2f"),
    Column("S_content", "S(xt,xc)", ".3f"),
    Column("S_style", "S(xt,xs)", ".3f"),
    Column("S_style_gain", "S gain", "+.3f"),
    Column("identity_content", "id(xt,xc)", ".3f"),
    Column("identity_style", "id(xt,xs)", ".3f"),
    Column("same_identity", f"id(xt,xc)<{SAME_PERSON}", "d"),
    Column("detail_output", "detail", ".2f"),
    Column("detail_ratio", "detail ratio", ".2f"),
    Column("protected_change", "protected Δ", ".2f"),
    Column("background_change", "background Δ", ".2f"),
    Column("prewarp_folds", "folds", "d"),
    Column("lowfreq_dE", "LF ΔE", ".2f"),
    Column("lowfreq_dE_max_region", "LF ΔE max", ".2f"),
    Column("hair_leakage", "hair coh", ".3f"),
    Column("stubble_moved", "stubble moved", "+.2f"),
    Column("coverage", "coverage", ".2f"),
    Column("detail_moved", "detail moved", "+.2f"),
    Column("detail_moved_cheeks", "detail moved cheeks", "+.2f"),
    Column("detail_moved_cheeks_skin", "detail moved cheeks (skin)", "+.2f"),
    Column("marks_kept", "marks kept", ".2f"),
    Column("marks_arrived", "marks arrived", ".2f"),
    Column("time_s", "s / image", ".1f"),
    Column("cpu_s", "CPU s / image", ".1f"),
)
# per pair (the method's row), worst low-frequency ΔE first
PAIR_COLUMNS = (
    Column("pair", "content ← style"), Column("method", "method"),
    Column("lowfreq_dE", "LF ΔE", ".2f"), Column("lowfreq_dE_max_region", "LF ΔE max", ".2f"),
    Column("S_style_gain", "S gain", "+.3f"), Column("identity_content", "id(xt,xc)", ".3f"),
    Column("hair_leakage", "hair coh", ".3f"), Column("hair_leakage_style", "hair coh (style)", ".3f"),
    Column("stubble_output", "specks out", ".2f"), Column("stubble_content", "specks content", ".2f"),
    Column("stubble_style", "specks style", ".2f"), Column("stubble_moved", "stubble moved", "+.2f"),
    Column("coverage", "coverage", ".2f"), Column("detail_moved", "detail moved", "+.2f"),
    Column("detail_moved_cheeks", "moved cheeks", "+.2f"),
    Column("detail_moved_cheeks_skin", "moved cheeks (skin)", "+.2f"), Column("marks_content", "marks c", "d"),
    Column("marks_kept", "kept", ".2f"), Column("marks_style", "marks s", "d"),
    Column("marks_arrived", "arrived", ".2f"), Column("protected_change", "protected Δ", ".2f"),
    Column("background_change", "background Δ", ".2f"), Column("time_s", "s", ".1f"),
)
PAPER_COLUMNS = (Column("method", "method"), Column("E_content", "E(xt,xc)", ".2f"),
                 Column("E_style", "E(xt,xs)", ".2f"), Column("S_content", "S(xt,xc)", ".2f"),
                 Column("S_style", "S(xt,xs)", ".2f"))


def resolve_pair_list(pair_list, portraits) -> list[tuple[str, str]]:
    """(content, style) id pairs from a :data:`PAIR_LISTS` name, a "c:s,c:s" string or a
    sequence of pairs; every id must have a portrait in ``portraits``."""
    if isinstance(pair_list, str):
        if pair_list in PAIR_LISTS:
            pairs = list(PAIR_LISTS[pair_list])
        else:
            try:
                pairs = [tuple(x.split(":")) for x in pair_list.split(",") if x.strip()]
            except ValueError:
                pairs = []
            if not pairs or any(len(p) != 2 for p in pairs):
                raise BadInputError(f"pair list {pair_list!r} is neither one of {', '.join(PAIR_LISTS)} nor "
                                    "'content:style,content:style,...'")
    else:
        pairs = [tuple(p) for p in pair_list]
    pairs = [(str(c).strip(), str(s).strip()) for c, s in pairs]
    missing = sorted({i for p in pairs for i in p if i not in portraits})
    if missing:
        raise BadInputError(f"pair list names people without an NNN_neutral.jpg portrait: {', '.join(missing)}")
    if any(c == s for c, s in pairs):
        raise BadInputError("a pair of the pair list has the same person as content and style")
    return pairs


def parse_methods(methods) -> tuple[str, ...]:
    """Methods from a comma-separated string or a sequence, validated, in Table 1 order."""
    if isinstance(methods, str):
        methods = methods.split(",")
    out = []
    for m in methods:
        m = str(m).strip().lower()
        if not m:
            continue
        if m not in METHODS:
            raise BadInputError(f"unknown method {m!r}: use one or more of {', '.join(METHODS)}")
        if m not in out:
            out.append(m)
    if not out:
        raise BadInputError(f"no method given: use one or more of {', '.join(METHODS)}")
    return tuple(m for m in METHODS if m in out)  # Table 1 order


def _default_transfer_fn():
    from ..transfer import transfer_with_info

    return transfer_with_info


def _inner_progress(progress, method: str):
    """Turn the transfer's per-iteration callback into a postfix on the outer bar."""
    if progress is None:
        return None
    count = 0

    def update(n: int = 1, **postfix):
        nonlocal count
        count += n
        shown = {k: v for k, v in postfix.items() if isinstance(v, (int, float, str))}
        progress(n=0, method=method, it=count, **shown)

    return update


def _item_config(method, content_path, style_path, preset, seed, options) -> dict:
    """What makes a stored result reusable: a different value means it must be redone."""
    return {"method": method, "content_file": Path(content_path).name, "style_file": Path(style_path).name,
            "preset": preset, "seed": int(seed), "options": dict(options)}


def _score(output, content, style, points_c, points_s, metrics_fn, extra=None) -> tuple[dict, str | None]:
    """Metrics of one output; NaN with the reason when no face is found in the output."""
    try:
        m = metrics_fn(output, content, style, points=(None, points_c, points_s), **(extra or {}))
        return {k: float(m.get(k, float("nan"))) for k in METRIC_KEYS}, None
    except NoFaceError as e:
        return {k: float("nan") for k in METRIC_KEYS}, f"no face in output: {e.message}"


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


def _default_metrics(output, content, style, **kw):
    import inspect

    from .. import metrics

    fn = metrics.transfer_metrics
    accepted = inspect.signature(fn).parameters
    return fn(output, content, style, **{k: v for k, v in kw.items() if k in accepted})


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


def _load_pair(content_path, style_path) -> dict:
    """Content and style images, their landmarks and the style aligned onto the content."""
    from ..geometry.style_align import align_style_to_content
    from ..landmarks import detect_face

    d = {"content": read_image(content_path), "style": read_image(style_path)}
    d["points_c"] = detect_face(d["content"], source=content_path).points68
    d["points_s"] = detect_face(d["style"], source=style_path).points68
    # one aligned style per pair for every method's detail ratio (same for all)
    d["aligned"] = align_style_to_content(d["style"], d["content"], style_points=d["points_s"],
                                          content_points=d["points_c"], refine=None, interpolation="lanczos").image
    return d


def _transfer_item(job: dict) -> dict:
    """One (pair, method) of the benchmark: transfer, score, write the image, its info and its
    result record (last). An engine item: run here (``job["load"]`` shares the pair's images
    between its methods) or in a worker, which gets paths only."""
    c, s, method, out = job["content"], job["style"], job["method"], Path(job["out"])
    d = job["load"]() if job.get("load") else _load_pair(job["content_path"], job["style_path"])
    metrics_fn = job.get("metrics_fn") or _default_metrics
    transfer_fn = job.get("transfer_fn") or _default_transfer_fn()
    options, preset, seed, device = job["options"], job["preset"], job["seed"], job["device"]
    key, image_path = job["key"], out / "images" / f"{job['key']}.png"
    extra = {"aligned_style": d["aligned"]} if metrics_fn is _default_metrics else {}
    t0, c0 = time.perf_counter(), time.process_time()
    output, info = transfer_fn(d["content"], d["style"], method=method, preset=preset, seed=seed,
                               device=device, progress=job.get("progress"), **options)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    info = dict(info or {})
    images = info.pop("images", None) or {}
    # score what is saved (8-bit), so re-measuring the PNG gives the same numbers
    output = to_uint8(np.asarray(output, dtype=np.float32)).astype(np.float32) / 255.0
    metrics, error = _score(output, d["content"], d["style"], d["points_c"], d["points_s"], metrics_fn, extra)
    write_image(image_path, output, overwrite=True)
    if method == "facetex" and images.get("style_native") is not None and info.get("region_box"):
        # the pre-warped style the optimiser got, in the content's frame
        x0, y0, x1, y1 = info["region_box"]
        pre = d["content"].copy()
        pre[y0:y1, x0:x1] = images["style_native"]
        write_image(out / "images" / f"{ResultStore.key(c, s, 'prewarp')}.png", pre, overwrite=True)
    write_json(image_path.with_suffix(".json"), json_safe({
        "content": job["content_path"], "style": job["style_path"], "method": method,
        "preset": preset, "seed": int(seed), "device": device, "options": options,
        "wall_s": wall, **no_image_data(dict(info or {})), "versions": job["versions"]}), overwrite=True)
    rec = {"content": c, "style": s, "method": method, "config": job["config"], "metrics": metrics,
           "metrics_error": error, "wall_s": wall, "cpu_s": cpu, "prewarp_folds": info.get("prewarp_folds"),
           "timings": dict(info.get("timings", {})),
           "image": str(image_path.relative_to(out))}
    ResultStore(out / "results").put(key, rec)  # last: its presence marks the item done
    return rec


def run_bench_transfer(data, out="bench_out/transfer", *, pairs: int = 5,
                       methods: Sequence[str] | str = METHODS, preset: str = "default", seed: int = 0,
                       size: int | None = None, iters=None, device: str = "cpu", overwrite: bool = False,
                       transfer_fn: Callable | None = None, metrics_fn: Callable | None = None,
                       progress: Callable | None = None, engine=None, pair_list=None,
                       transfer_options: dict | None = None) -> dict:
    """Run the FaceTex §3.1 benchmark and write its tables, figures and per-pair results to ``out``.

    ``transfer_fn(content, style, *, method, preset, seed, device, progress, **options)``
    returns ``(image, info)`` (default :func:`facetex.transfer.transfer_with_info`);
    ``size`` is passed to it as the option ``size`` when given. Finished (pair, method)
    results in ``out`` are reused unless ``overwrite``; a stored result made with other
    settings raises OutputError. ``progress(n, **postfix)`` advances once per (pair,
    method) and gets ``n=0`` updates with the transfer's own iteration count.
    ``engine`` (:mod:`facetex.batch.engines`, started): the (pair, method) transfers run as its
    items (``transfer_fn`` / ``metrics_fn`` must then be picklable); default: one after another here.
    ``pair_list``: a name of :data:`PAIR_LISTS` ("issue22") or a sequence of (content,
    style) ids: its first ``pairs`` pairs are run instead of hashed ones.
    ``transfer_options``: more options for every transfer (e.g. ``keep_shading``, ``marks``).
    Returns the output paths, the Table 1 rows and the counts of run / reused items."""
    methods = parse_methods(methods)
    if preset not in PRESETS:
        raise BadInputError(f"unknown preset {preset!r}: use one of {', '.join(PRESETS)}")
    if size is not None and int(size) < 16:
        raise BadInputError(f"--size must be at least 16 px, got {size}")
    data = Path(data)
    portraits = list_portraits(data, tag="neutral")
    if len(portraits) < 2:
        raise BadInputError(f"found {len(portraits)} person(s) with an NNN_neutral.jpg portrait, "
                            "need at least 2 different people", path=data)
    if pair_list is None:
        chosen = select_pairs(list(portraits), int(pairs), seed=seed)
    else:
        chosen = resolve_pair_list(pair_list, portraits)[:int(pairs)]
    out = check_out_dir(out)
    (out / "images").mkdir(exist_ok=True)
    store = ResultStore(out / "results")
    options = {} if size is None else {"size": int(size)}
    options.update(transfer_options or {})
    if iters is not None:
        options["iters"] = list(iters)
    transfer_fn = transfer_fn or _default_transfer_fn()
    if metrics_fn is None:
        metrics_fn = _default_metrics
    settings = {"data": str(data.resolve()), "seed": int(seed), "preset": preset, "methods": list(methods),
                "n_pairs": len(chosen), "pairs_requested": int(pairs), "size": size, "device": device,
                "pair_list": pair_list if isinstance(pair_list, str) or pair_list is None else "explicit",
                "transfer_options": dict(transfer_options or {}),
                "versions": versions()}

    from ..batch import map_items
    from ..batch.engines import InlineEngine

    records: dict[tuple[str, str, str], dict] = {}
    n_run = n_reused = 0
    here = engine is None or isinstance(engine, InlineEngine)
    jobs: list[dict] = []

    def finished(batch):
        def done(n=1, index=0, result=None):
            nonlocal n_run
            job = batch[index]
            records[(job["content"], job["style"], job["method"])] = result
            n_run += 1
            if progress:
                progress(n=1, pair=f"{job['content']}/{job['style']}", method=job["method"], done="run")
        return done

    for c, s in chosen:
        loaded: dict = {}

        def load():
            if not loaded:
                loaded.update(_load_pair(portraits[c], portraits[s]))
            return loaded

        pair_jobs = []
        for method in (NONE,) + tuple(methods):
            key = store.key(c, s, method)
            config = _item_config(method, portraits[c], portraits[s], preset, seed,
                                  {} if method == NONE else options)
            image_path = out / "images" / f"{key}.png"
            rec = None if overwrite else store.get(key)
            if rec is not None and (method == NONE or image_path.is_file()):
                if rec.get("config") != config:
                    raise OutputError(f"holds a result made with other settings ({rec.get('config')}): "
                                      "pass --overwrite to recompute or choose another --out",
                                      path=store.path(key))
                records[(c, s, method)] = rec
                n_reused += method != NONE
                if progress and method != NONE:
                    progress(n=1, pair=f"{c}/{s}", method=method, done="reused")
                continue
            if method == NONE:
                d = load()
                extra = {"aligned_style": d["aligned"]} if metrics_fn is _default_metrics else {}
                metrics, error = _score(d["content"], d["content"], d["style"], d["points_c"], d["points_s"],
                                        metrics_fn, extra)
                rec = {"content": c, "style": s, "method": NONE, "config": config, "metrics": metrics,
                       "metrics_error": error, "wall_s": 0.0, "timings": {}, "image": None}
                store.put(key, rec)
                records[(c, s, method)] = rec
                continue
            pair_jobs.append({"key": key, "content": c, "style": s, "method": method, "out": str(out.resolve()),
                              "content_path": str(portraits[c]), "style_path": str(portraits[s]), "preset": preset,
                              "seed": seed, "device": device, "options": options, "config": config,
                              "versions": settings["versions"], "transfer_fn": transfer_fn, "metrics_fn": metrics_fn,
                              **({"load": load, "progress": _inner_progress(progress, method)} if here else {})})
        if here:  # one after another, as before: the pair's images are loaded once for all its methods
            map_items(InlineEngine(), _transfer_item, pair_jobs, progress=finished(pair_jobs))
            _write_pair_zoom(out, c, s, portraits, methods, records, load)
        else:  # the engine's workers load the pair themselves
            jobs += pair_jobs
    if not here:
        map_items(engine, _transfer_item, jobs, progress=finished(jobs))
        for c, s in chosen:
            _write_pair_zoom(out, c, s, portraits, methods, records,
                             lambda c=c, s=s: _load_pair(portraits[c], portraits[s]))

    rows = _summary_rows(records, chosen, (NONE,) + tuple(methods))
    files = {"table_md": out / "table.md", "table_csv": out / "table.csv", "grid": out / "grid.png",
             "scatter": out / "scatter.png", "results": out / "results.json"}
    write_json(files["results"], json_safe({
        "bench": "transfer",
        "settings": settings,
        "pairs": [{"content": c, "style": s, "content_path": str(portraits[c]), "style_path": str(portraits[s]),
                   "results": {m: {k: records[(c, s, m)][k] for k in
                                   ("metrics", "metrics_error", "wall_s", "timings", "image")}
                               for m in (NONE,) + tuple(methods)}}
                  for c, s in chosen],
        "table": rows,
        "paper_table1": PAPER_TABLE1,
    }), overwrite=True)
    write_text(files["table_md"], _table_markdown(rows, settings, _pair_rows(records, chosen, tuple(methods))))
    write_text(files["table_csv"], csv_table((Column("method_id", ""),) + TABLE_COLUMNS, rows))
    files["zoom"] = _write_zoom(out / "zoom.png", out, chosen)
    _write_grid(files["grid"], out, chosen, portraits, methods, records)
    _write_scatter(files["scatter"], records, chosen, methods)
    return {"out": out, "files": files, "pairs": chosen, "table": rows, "n_run": n_run, "n_reused": n_reused}


# --------------------------------------------------------------------------- CLI
def register_bench(bench_subparsers) -> argparse.ArgumentParser:
    """Add ``transfer`` to the ``facetex bench`` sub-parsers."""
    from ..cli._common import add_overwrite, add_seed_device, bounded_int, positive_int
    from ..cli.cmd_transfer import _iters
    from ._common import add_bench_options

    p = bench_subparsers.add_parser(
        "transfer", help="FaceTex §3.1 benchmark: Table 1, Figures 3 and 4",
        description="Run Neural Style, MRF-CNN and FaceTex on content/style pairs of different people "
                    "and write table.md/.csv, grid.png, scatter.png, zoom.png and results.json. Resumable: finished "
                    "(pair, method) results in --out are reused.")
    add_bench_options(p, "transfer", f"data root holding {DATA_SUBFOLDER}/, or a folder of NNN_neutral.jpg portraits")
    p.add_argument("--pairs", type=positive_int, default=5, help="number of content/style pairs (default 5)")
    p.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated subset of {','.join(METHODS)}")
    p.add_argument("--preset", choices=PRESETS, default="default", help="transfer parameters (default: default)")
    p.add_argument("--size", type=bounded_int(32, 4096), default=None, help="working size in px passed to the transfer (optional)")
    p.add_argument("--iters", type=_iters, default=None, metavar="N,N,N",
                   help="L-BFGS iterations per level passed to the transfer, e.g. 5,5,5 for a quick run "
                        "(default: the preset's)")
    p.add_argument("--pair-list", metavar="NAME|C:S,...", default=None,
                   help=f"run these (content:style) pairs instead of hashed ones: {', '.join(PAIR_LISTS)} (the "
                        "documented issue-22 list, 22 pairs) or e.g. 083:037,010:003; --pairs takes its first N")
    p.add_argument("--keep-shading", choices=("on", "off"), default=None,
                   help="FaceTex: keep the content's low-frequency colour and shading (default: the preset's)")
    p.add_argument("--marks", choices=("content", "style", "off"), default=None,
                   help="FaceTex: keep the content's marks or bring the style's (default: the preset's)")
    add_seed_device(p)
    add_overwrite(p)
    from ..cli._common import add_engine_options

    add_engine_options(p, jobs_help="local: worker processes, one (pair, method) each (default: the available "
                                    "CPUs; --jobs 1: one after another in this process); ray: items in flight")
    p.set_defaults(func=run)
    return p


def _finish_options(args) -> dict:
    """The transfer options of ``--keep-shading`` / ``--marks`` (only those given)."""
    out = {}
    if getattr(args, "keep_shading", None) is not None:
        out["keep_shading"] = args.keep_shading == "on"
    if getattr(args, "marks", None) is not None:
        out["marks"] = args.marks
    return out


def run(args) -> int:
    from ..cli._common import check_device, progress_bar
    from ._common import data_folder, data_root, finish_bench

    methods = parse_methods(args.methods)
    check_device(args.device)  # before the work
    data = data_folder(data_root(args.data), DATA_SUBFOLDER)
    n_people = len(list_portraits(data, tag="neutral"))
    total = max(1, min(int(args.pairs), n_people * (n_people - 1))) * len(methods)
    if args.pair_list is not None:
        listed = resolve_pair_list(args.pair_list, list_portraits(data, tag="neutral"))
        total = max(1, min(int(args.pairs), len(listed)))
        total *= len(methods)
    from ..cli._common import engine_from_args

    with engine_from_args(args, inline_single=True) as engine, \
            progress_bar(total=total, desc="bench transfer", unit="run", disable=args.quiet) as update:
        result = run_bench_transfer(data, args.out, pairs=args.pairs, methods=methods, preset=args.preset,
                                    seed=args.seed, size=args.size, iters=args.iters, device=args.device,
                                    overwrite=args.overwrite, progress=update, engine=engine,
                                    pair_list=args.pair_list, transfer_options=_finish_options(args))
    table = Path(result["files"]["table_md"]).read_text(encoding="utf-8")
    finish_bench(args, "transfer", result["out"], result["files"], inputs={"data": data},
                 settings={"data": str(data)},
                 summary={"run": result["n_run"], "reused": result["n_reused"], "table": json_safe(result["table"])},
                 table=table)
    return 0
