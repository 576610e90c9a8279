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

from .._methods import METHOD_COLOURS, METHOD_TITLES
from ..errors import BadInputError, NoFaceError, OutputError
from ..io import read_image, to_uint8, write_image, write_json
from ._common import (
    Column,
    ResultStore,
    check_out_dir,
    csv_table,
    json_safe,
    list_portraits,
    no_image_data,
    select_pairs,
    versions,
    write_text,
)
from ._transfer_spec import (  # the bench's names, here as before (tests and the report read them)
    DATA_SUBFOLDER,
    GRID_ORDER,  # noqa: F401
    ISSUE22_PAIRS,  # noqa: F401
    METHODS,
    METRIC_KEYS,
    NONE,
    PAIR_COLUMNS,  # noqa: F401
    PAIR_LISTS,
    PAPER_COLUMNS,  # noqa: F401
    PAPER_TABLE1,
    PRESETS,
    SAME_PERSON,  # noqa: F401
    TABLE_COLUMNS,
    ZOOM_ROWS,  # noqa: F401
    parse_methods,
    resolve_pair_list,
)
from ._transfer_summary import (
    _pair_rows,
    _summary_rows,
    _table_markdown,
    _write_grid,
    _write_pair_zoom,
    _write_scatter,
    _write_zoom,
)

__all__ = [  # in the order of the reference page
    "METHOD_TITLES", "METHOD_COLOURS", "METHODS", "PRESETS", "PAPER_TABLE1", "resolve_pair_list",
    "parse_methods", "run_bench_transfer", "register_bench", "run",
]


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


def _default_metrics(output, content, style, **kw):
    import inspect

    from .. import metrics

    fn = metrics.transfer_metrics
    accepted = inspect.signature(fn).parameters
    return fn(output, content, style, **{k: v for k, v in kw.items() if k in accepted})


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
