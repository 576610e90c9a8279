"""``facetex bench puppet``: persona puppetry driven by talking-face clips (Tom Hanks §4, §6).

The paper has no quantitative puppetry benchmark ("Evaluating a puppetry system objectively
is extremely hard"); we measure what a viewer of the composited videos sees, on **every
persona × every clip** (default: the collections ``DATA/lfw/*`` × the clips ``DATA/grid``,
6 × 6 = 36 runs), and report each run and the **worst** run of every measure, not only means.
Landmarks of a rendered frame are re-detected by dlib (68 points) on a copy upscaled to
720 px (:data:`MEASURE_SIDE`; its predictor is noisy on GRID's ~100 px faces), as the median of 14
fits in jittered boxes and their mirror images (:func:`~facetex._landmark_fit.jittered_landmarks`:
one fit read a still closed mouth 0.005 and 0.051 open on two frames), the driver's the same way
on its own frame; masks are cut at the driver's tracked landmarks (the composite sits
there) and, for the composite, kept where its mask alpha > 0.9 (the puppet, not the driver,
shows there). Per run:

* **mouth**: opening = inner-lip gap / outer-eye-corner distance (:func:`mouth_opening`), on
  every frame; least-squares **slope** of the puppet's on the driver's (target 0.8–1.3) and
  Pearson **r** (target >= 0.85);
* **cheek ΔE** (composite mode): CIE76 ΔE (CIELAB, L 0..100, D65) between the mean Lab colour
  of the composite's two cheek patches and the mean of the driver's own frame on the same
  pixels (:func:`cheek_mask`: discs of radius 0.12 × eye-corner distance at the centroid of
  jaw point 1 (15), nostril 31 (35) and lower lid 41 (46): skin below the eye, lateral to the
  nose), the median over frames; target <= 8;
* **under-eye ΔL*** (no target): mean CIELAB L* of the composite minus the driver's own frame on two
  discs below the lower lids (:func:`under_eye_mask`), median over frames; < 0 darker. The cheek ΔE
  missed a dark persona's under-eye circles kept as a dark band on a pale 1000 px driver (-13 to -17
  L* there, cheek ΔE 4.5); the "worst" row shows the value farthest from 0;
* **eye openness**: eye aspect ratio (:func:`eye_aspect_ratio`, both eyes averaged) of the
  puppet over the driver's, mean over the frames where the driver's eyes are open (EAR >= 0.75
  × its 90th percentile in the clip): :func:`eye_openness_ratio`, target >= 0.8; **eye r**:
  Pearson r of the two EAR series when the driver blinks (some frame below that level; else
  "–"): :func:`blink_correlation`, near 1 when the puppet blinks with the driver;
* **sharpness**: variance of the Laplacian (3 × 3, luminance) of the composite over the
  driver's own frame on the same face-skin pixels (:func:`face_skin_mask`: inside jaw and
  brows, eyes, brows and lips cut out; :func:`sharpness_ratio`), median over frames; target
  >= 0.75; the same on both images at half size (``cv2.INTER_AREA``) as **sharpness at ½
  size** (no target: the detail a pixel-scale grain does not give) and on the eyes (dilated eye
  outlines) as **eye sharpness** (no target);
* **identity**: on every :data:`ID_STEP`-th tracked frame, the dlib FaceRecognitionNet
  descriptor of the composite is compared with the mean descriptor of the persona's photos
  (up to :data:`ID_PHOTOS` evenly spaced) and with the driver's mean (every 5th frame):
  **closer** = fraction of those frames nearer the persona (no face found counts as not
  closer), target >= 80 %; also the mean distance to each and the fraction < 0.6;
* **boundary colour step**: CIE76 ΔE between bands just inside and just outside the edge of
  the composite mask (alpha 0.5), per angular sector, averaged; divided by the driver's own
  step at the same place in its original frame (target <= 2). The same ratio for the puppet
  pasted without colour/lighting transfer and Poisson blending ("pasted", every 5th frame);
* **expression texture**: mean |texture − static average texture| (0-255) in the mouth region
  of the texture, on the frames where the driver's mouth is open (top quarter of the opening);
* **closed-mouth lift Δ**: mouth-corner lift (eye distances) of the puppet minus the driver's, both
  as dlib reads them, on the driver's most-closed third of frames
  (:func:`rest_lift_difference`): > 0 the puppet smiles on a closed, neutral mouth;
* **lost frames** and a **partial-face check** (the first clip slid half out of its frame; every
  frame with >= 10 % of the face box outside must be rejected, every whole face kept);
* **flicker**: mean |frame-to-frame change| (0-255) of the composited face on still frames.

**Stress** (``--stress``): four harder copies of the clips (mirrored and side-lit, rotated with the
face shrunk, dimmed with sensor noise, the skin darkened to a dark-skinned speaker's;
:mod:`facetex.bench._stress_clips`) are runs like the others.

**Portraits** (``--portraits N``): N high-resolution drivers, still pairs of studio portraits
(``DATA/frl-london``, 1000 px: a closed neutral face, then the same person's open smile; chosen
to span skin lightness, :mod:`facetex.bench._portrait_clips`), run at their own size
(``--portrait-size``, default native): what GRID's 360 px clips cannot show (soft skin and lips
next to a sharp frame, a dark persona's lids on a pale face at 100 %).

**Worst runs**: per run, each target measure's relative shortfall ``s`` (0 when met; below a
lower bound lo: (lo − v) / lo, above an upper bound hi: (v − hi) / hi; a measure that could not
be taken: 1) gives the score Σ (1[s > 0] + s) over the targets (:func:`run_score`: failed targets
first, then how far). The three highest are the worst runs; their 100 % sheets (driver |
composite | face mode at the driver's most closed, widest-open and middle mouth frames) are
copied as ``worst<k>_<persona>__<clip>.png``.

Outputs: table.md, table.csv, results.json (rows, mean, worst per measure, worst runs); per run
in ``<persona>/``: a contact sheet of 8 frames, the 3-frame sheet at 100 % (``*_sheet3_100.png``),
zoomed crops of the most open-mouth frame, and for the first run a side-by-side MP4;
``runs/<persona>__<clip>.json`` per finished run (reused with ``resume``).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..errors import BadInputError
from ._common import (
    ResultStore,
    check_out_dir,
    csv_table,
    json_safe,
    markdown_table,
    versions,
    write_text,
)
from ._puppet_clip import MEASURE_VERSION, _collection_descriptor, _evaluate_clip, _partial_check, shifted_clip
from ._portrait_clips import HOLD, portrait_clips
from ._stress_clips import stress_clips, stress_sources
from .puppet_measures import (
    COLUMNS,
    ID_PHOTOS,
    PARTIAL_OUTSIDE,
    STEP_RATIO_TARGET,
    TARGETS,
    _series_measures,
    _shortfall,
    _worst_value,
    blink_correlation,
    cheek_delta_e,
    cheek_mask,
    lightness_difference,
    under_eye_mask,
    eye_aspect_ratio,
    eye_mask,
    eye_openness_ratio,
    face_skin_mask,
    rest_lift_difference,
    failed_targets,
    headroom,
    mouth_slope,
    run_score,
    sharpness_ratio,
    sheet_frames,
    worst_runs,
)

__all__ = ["register_bench", "run_bench_puppet", "mouth_slope", "shifted_clip", "eye_aspect_ratio",
           "eye_openness_ratio", "cheek_mask", "cheek_delta_e", "under_eye_mask", "lightness_difference",
           "face_skin_mask", "eye_mask", "sharpness_ratio",
           "blink_correlation", "rest_lift_difference", "run_score", "failed_targets", "worst_runs", "sheet_frames",
           "TARGETS"]

def _persona_file(puppet, out: Path, progress) -> str:
    """A .persona file for ``puppet``: itself, or the photo folder's persona built once and cached in ``out``."""
    from ..persona import build_persona
    from ..persona._persona_file import _read_header

    p = Path(puppet)
    if p.is_file():
        _read_header(p)  # not a persona: one line naming it, before any work
        return str(p)
    if not p.is_dir():
        raise BadInputError("puppet not found: give a .persona file or a photo folder", path=p)
    cached = out / f"{p.name}.persona"
    if cached.is_file():
        header, _, _ = _read_header(cached)
        if Path(header.get("source", "")).resolve() == p.resolve():
            return str(cached)
    build_persona(p, jobs=1, progress=progress).save(cached, overwrite=True)
    return str(cached)


def _data_paths(data, drivers, puppets) -> tuple[Path, list[Path]]:
    """(driver clips, puppets): the given ones, else ``DATA/grid`` and every folder of ``DATA/lfw``."""
    if isinstance(puppets, (str, os.PathLike)):
        puppets = [puppets]
    root = data or os.environ.get("FACETEX_DATA")
    if drivers is None or not puppets:
        if not root:
            raise BadInputError("no data: give --data DIR (with grid/ and lfw/<person>/), set FACETEX_DATA, "
                                "or give --drivers and --puppets")
        root = Path(root)
        drivers = root / "grid" if drivers is None else drivers
        if not puppets:
            lfw = root / "lfw"
            puppets = sorted(d for d in lfw.iterdir() if d.is_dir()) if lfw.is_dir() else []
            if not puppets:
                raise BadInputError("no photo collections (lfw/<person>/) in the data folder: give --puppets",
                                    path=lfw)
    return Path(drivers), [Path(p) for p in puppets]


def _persona_names(files: Sequence[str]) -> list[str]:
    """Short unique names of the persona files (their stems, numbered when two are the same)."""
    stems = [Path(f).stem for f in files]
    return [s if stems.count(s) == 1 else f"{s}-{k}" for k, s in enumerate(stems)]


#: the portrait pairs' folder inside --data / $FACETEX_DATA (``--portraits``)
PORTRAIT_SUBFOLDER = "frl-london"

_WORKER_CACHE: dict = {}  # persona file -> persona, per worker process (the items are persona-major)


def _bench_item(p: dict):
    """One item of the benchmark in a worker (``engine``): a persona's identity reference, a
    run's evaluation or the partial-face check; the persona is loaded once per worker."""
    from ..persona import load_persona
    from ..puppet.puppetry import PuppetParams

    if p["kind"] == "partial":
        return _partial_check(Path(p["clip"]), Path(p["out"]), p["max_frames"])
    if p["kind"] == "reference":
        return _collection_descriptor(p["persona_file"]).tolist()
    if p["persona_file"] not in _WORKER_CACHE:
        _WORKER_CACHE.clear()
        _WORKER_CACHE[p["persona_file"]] = load_persona(p["persona_file"])
    persona = _WORKER_CACHE[p["persona_file"]]
    try:
        row = _evaluate_clip(Path(p["clip"]), persona, np.asarray(p["reference"]), Path(p["out"]) / p["name"],
                             size=p["size"], max_frames=p["max_frames"],
                             params=PuppetParams(shape=p["shape"], weights=p["weights"],
                                                 weight_smoothing=p["weight_smoothing"]),
                             write_media=p["write_media"], progress=None, name=p["name"],
                             cache=Path(p["out"]) / "_cache" / f"driver_{Path(p['clip']).stem}_{p['size']}_"
                                                               f"{p['max_frames']}_m{MEASURE_VERSION}.npz")
    except Exception as e:  # noqa: BLE001 - one failed run is a row of the table, not the end of the bench
        row = {"run": f"{p['name']}/{Path(p['clip']).stem}", "persona": p["name"], "clip": Path(p["clip"]).stem,
               "error": f"{type(e).__name__}: {e}", "frames": 0, "lost": 0}
        row["score"], row["failed"] = run_score(row), failed_targets(row)
    row["settings"] = p["settings"]
    if p.get("store"):
        ResultStore(p["store"]).put(p["key"], json_safe(row))
    return row


def run_bench_puppet(drivers=None, puppet=None, out="bench_out/puppet", *, puppets=None, data=None,
                     clips: int | None = None, size: int | None = 256, max_frames: int | None = None,
                     texture_shape: str = "collection", weights: str = "regional",
                     weight_smoothing: float | None = None, partial: bool = True, resume: bool = False,
                     stress: bool = False, portraits: int = 0, portrait_folder=None,
                     portrait_size: int | None = None, progress: Callable | None = None, engine=None) -> dict:
    """Run the puppetry benchmark: every ``*.mpg`` / ``*.mp4`` in ``drivers`` (the first ``clips``)
    drives every persona of ``puppets`` (``puppet``: one or a list; .persona files, or photo
    folders built once and cached in ``out``); ``data`` (or FACETEX_DATA) supplies the defaults
    ``grid/`` and every folder of ``lfw/``. Writes table.md, table.csv, results.json, per run a
    contact sheet, 100 % sheets and zoomed crops (in ``out/<persona>/``), for the first run a
    side-by-side MP4, and the three worst runs' 100 % sheets (module docstring).
    ``resume``: reuse the runs already stored in ``out/runs`` with the same settings. ``stress``:
    also a mirrored side-lit, a rotated small-face and a dim noisy copy of the clips
    (:mod:`facetex.bench._stress_clips`, written to ``out/stress/``), each driving every persona.
    ``portraits``: also that many still-pair clips of ``portrait_folder`` (default ``DATA/frl-london``;
    :mod:`facetex.bench._portrait_clips`, written to ``out/portraits/``), run at ``portrait_size``
    (None: their own size). ``engine`` (:mod:`facetex.batch.engines`, started): the runs (and the partial-face check)
    run as its items, in parallel; default: one after another in this process.
    Returns {"out", "rows", "summary", "worst", "worst_runs", "partial", "files", "targets_met"}."""
    import hashlib
    from dataclasses import replace

    from ..io import atomic_path
    from ..puppet.puppetry import PuppetParams

    drivers, puppet_paths = _data_paths(data, drivers, puppets if puppets is not None else puppet)
    if not drivers.exists():
        raise BadInputError("driver clips not found", path=drivers)
    files = sorted(f for f in drivers.iterdir() if f.suffix.lower() in (".mpg", ".mp4", ".mov", ".avi", ".mkv")) \
        if drivers.is_dir() else [drivers]
    if not files:
        raise BadInputError("no driver videos (.mpg/.mp4/.mov/.avi/.mkv) found", path=drivers)
    if clips is not None and clips < 1:
        raise BadInputError(f"--clips must be at least 1, got {clips}")
    files = files[: clips or None]
    for p in puppet_paths:
        if not p.exists():
            raise BadInputError("puppet not found: give .persona files or photo folders", path=p)
    params = PuppetParams(shape=texture_shape, weights=weights)
    if weight_smoothing is not None:
        params = replace(params, weight_smoothing=float(weight_smoothing))
    params.texture_params()  # unknown weights, negative smoothing: an error before any work
    out = check_out_dir(out)
    if stress:
        files = files + stress_clips(files, out, max_frames=max_frames)
    portrait_files = []
    if portraits:
        if portrait_folder is None:
            root = data or os.environ.get("FACETEX_DATA")
            if not root:
                raise BadInputError("--portraits needs the portrait folder: give --data DIR (with frl-london/), "
                                    "set FACETEX_DATA, or give --portrait-folder")
            portrait_folder = Path(root) / PORTRAIT_SUBFOLDER
        portrait_files = portrait_clips(portrait_folder, out, portraits)
        files = files + portrait_files
    persona_files = [_persona_file(p, out, progress) for p in puppet_paths]
    names = _persona_names(persona_files)
    from ..batch.engines import InlineEngine

    inline = engine is None or isinstance(engine, InlineEngine)

    def run_items(items, done=None):
        if inline:
            res = []
            for k, it in enumerate(items):
                res.append(_bench_item(it))
                if done:
                    done(index=k, result=res[-1])
            return res
        from ..batch import map_items

        return map_items(engine, _bench_item, items, progress=done)

    # the identity references (~40 descriptors each), cached per persona file (path, size, time)
    ref_cache = []
    for f in persona_files:
        st = os.stat(f)
        tag = hashlib.sha256(f"{Path(f).resolve()}\0{st.st_size}\0{st.st_mtime_ns}\0{ID_PHOTOS}".encode()).hexdigest()
        ref_cache.append(out / "_cache" / f"reference_{Path(f).stem}_{tag[:12]}.npy")
    missing = [k for k, c in enumerate(ref_cache) if not c.is_file()]
    new = run_items([{"kind": "reference", "persona_file": str(Path(persona_files[k]).resolve())} for k in missing])
    for k, d in zip(missing, new):
        ref_cache[k].parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(ref_cache[k]) as tmp:
            with open(tmp, "wb") as fh:
                np.save(fh, np.asarray(d, np.float64))
    refs = [np.load(c).tolist() for c in ref_cache]
    store = ResultStore(out / "runs")
    items, rows, todo = [], [], []
    for pf, name, ref in zip(persona_files, names, refs):
        st = os.stat(pf)
        for c in files:
            # a portrait clip is 2 x HOLD frames at its own size: cut short it would never smile
            c_size, c_frames = (portrait_size, None) if c in portrait_files else (size, max_frames)
            settings = {"persona_file": str(Path(pf).resolve()), "persona_bytes": st.st_size,
                        "persona_mtime": st.st_mtime, "clip": str(c.resolve()), "size": c_size,
                        "max_frames": c_frames, "shape": texture_shape, "weights": weights,
                        "weight_smoothing": params.weight_smoothing}
            key = ResultStore.key(name, c.stem)
            old = store.get(key) if resume else None
            if old is not None and old.get("settings") == json_safe(settings):
                rows.append(old)
                continue
            rows.append(None)
            todo.append(len(rows) - 1)
            items.append({"kind": "clip", "clip": str(c), "persona_file": settings["persona_file"], "name": name,
                          "reference": list(ref), "out": str(out.resolve()), "size": c_size,
                          "max_frames": c_frames, "shape": texture_shape, "weights": weights,
                          "weight_smoothing": params.weight_smoothing, "write_media": len(rows) == 1,
                          "settings": settings, "store": str(store.folder), "key": key})
    if partial:
        items.append({"kind": "partial", "clip": str(files[0]), "out": str(out.resolve()), "max_frames": max_frames})

    def done(n=1, index=0, result=None):
        if progress and items[index]["kind"] == "clip":
            progress(n=int(result.get("frames", 1)), clip=Path(items[index]["clip"]).name)

    results = run_items(items, done)
    for k, r in zip(todo, results):
        rows[k] = r
    part = results[len(todo)] if partial else None
    return _write_tables(out, rows, part, drivers=drivers, files=files, persona_files=persona_files,
                         puppet_paths=puppet_paths, size=size, weights=weights, params=params, max_frames=max_frames,
                         portraits=(portrait_files, portrait_size))


def _write_tables(out: Path, rows: list, part, *, drivers, files, persona_files, puppet_paths, size, weights,
                  params, max_frames, portraits=((), None)) -> dict:
    """table.md, table.csv, results.json and the worst runs' sheets of a finished bench."""
    from ..io import read_image, write_json

    rows = [_series_measures(dict(r)) for r in rows]
    keys = [c.key for c in COLUMNS[2:]]
    summary = {"persona": "mean", "clip": ""}
    worst = {"persona": "worst", "clip": ""}
    worst_run = {}
    for k in keys:
        vals = [r.get(k) for r in rows]
        fin = [v for v in vals if isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)]
        summary[k] = float(np.mean(fin)) if fin else float("nan")
        worst[k] = _worst_value(k, vals)
        if np.isfinite(worst[k]):
            worst_run[k] = next((r["run"] for r in rows if r.get(k) == worst[k]), None)
    summary["frames"], summary["lost"] = int(sum(r.get("frames", 0) for r in rows)), \
        int(sum(r.get("lost", 0) for r in rows))
    bad = worst_runs(rows)
    n_fail = {k: sum(_shortfall(k, r.get(k)) > 0 for r in rows) for k in TARGETS}
    head = (f"# Puppetry benchmark\n\n{len(persona_files)} persona(s) × {len(files)} clip(s) from `{drivers}` = "
            f"{len(rows)} runs; panel size {size or 'native'}; texture weights: {weights}; weight smoothing: "
            f"{params.weight_smoothing:g} s. " +
            (f"Of the clips, {len(portraits[0])} are portrait pairs (`{portraits[0][0].parent}`: "
             + ", ".join(f"`{p.stem}`" for p in portraits[0]) + f") at {portraits[1] or 'their own'} px. "
             if portraits[0] else "") + "Personas: " +
            ", ".join(f"`{Path(f).name}`" for f in persona_files) + ".\n\n"
            "Targets per run (issue 21): mouth slope 0.8–1.3 and r >= 0.85; cheek ΔE to the driver <= 8 (CIELAB, "
            "composite); eye openness >= 0.8 of the driver's; face sharpness >= 0.75 of the driver's; composite "
            "closer to the persona than to the driver (dlib descriptor) on >= 80 % of sampled frames. "
            "Fail score: failed targets + their relative shortfalls (0 = all met).\n\n")
    worst_md = ["", "## Worst run per measure", "", "| measure | target | worst | run | runs failing |",
                "|---|---|---:|---|---:|"]
    titles = {c.key: c for c in COLUMNS}
    for k, (lo, hi) in TARGETS.items():
        tgt = f"{lo:g}–{hi:g}" if lo is not None and hi is not None else f">= {lo:g}" if lo is not None else \
            f"<= {hi:g}"
        worst_md.append(f"| {titles[k].title} | {tgt} | {titles[k].format(worst[k])} | {worst_run.get(k) or '–'} | "
                        f"{n_fail[k]}/{len(rows)} |")
    worst_md += ["", f"## The {len(bad)} worst runs (by fail score, then by the smallest margin to a target)", ""]
    sheets = {}
    for old in out.glob("worst[0-9]_*.png"):  # a resumed run's earlier worst runs: not this table's
        old.unlink()
    for rank, i in enumerate(bad, 1):
        r = rows[i]
        src = (r.get("media") or {}).get("sheet3_100")
        line = f"{rank}. `{r['run']}`: score {r['score']:.2f}, failed: {', '.join(r.get('failed') or []) or '–'}"
        margin, near = headroom(r)
        if near is not None:
            line += f" (meets every target; closest: {titles[near].title} {titles[near].format(r.get(near))}, " \
                    f"margin {margin:.0%})"
        if r.get("error"):
            line += f"; error: {r['error']}"
        if src and Path(src).is_file():
            dst = out / f"worst{rank}_{ResultStore.key(r['persona'], r['clip'])}.png"
            _write_worst_sheet(dst, read_image(src), r)
            sheets[f"worst{rank}"] = dst
            line += f"; sheet `{dst.name}` (rows: driver's most closed, widest-open, middle mouth frames " \
                    f"{r.get('sheet_frames')}; columns: driver | composite | face mode; 100 %)"
        worst_md.append(line)
    table_rows = rows + [summary, worst]
    ok = {k: n_fail[k] == 0 for k in TARGETS}
    ok["boundary"] = bool(rows) and all(np.isfinite(r.get("step_ratio", np.nan))
                                        and r["step_ratio"] <= STEP_RATIO_TARGET for r in rows)
    tail = "\n" + "\n".join(worst_md) + "\n\n" + "; ".join(f"{k} target met: {v}" for k, v in ok.items()) + "\n"
    errs = [r for r in rows if r.get("error")]
    if errs:
        tail += "\nFailed runs: " + "; ".join(f"{r['run']}: {r['error']}" for r in errs) + "\n"
    lost = {r["run"]: r["lost_causes"] for r in rows if r.get("lost")}
    if lost:
        tail += "\nLost frames by cause: " + "; ".join(f"{c}: {v}" for c, v in lost.items()) + "\n"
    if part is not None:
        ok["partial"] = (part["partial_rejected"] == part["partial_frames"]
                         and part["whole_kept"] == part["whole_frames"])
        tail += (f"\nPartial faces (`{part['clip']}`, the first clip slid out of its frame): "
                 f"{part['partial_rejected']}/{part['partial_frames']} frames with >= {PARTIAL_OUTSIDE:.0%} of the "
                 f"face outside rejected, {part['whole_kept']}/{part['whole_frames']} whole-face frames kept "
                 f"(causes: {part['lost_causes']}); target met: {ok['partial']}\n")
    paths = {"table_md": out / "table.md", "table_csv": out / "table.csv", "results": out / "results.json"}
    write_text(paths["table_md"], head + markdown_table(COLUMNS, table_rows) + tail)
    write_text(paths["table_csv"], csv_table(COLUMNS, table_rows))
    worst_list = [{"run": rows[i]["run"], "score": rows[i]["score"], "failed": rows[i].get("failed"),
                   "sheet": str(sheets.get(f"worst{k}", ""))} for k, i in enumerate(bad, 1)]
    write_json(paths["results"], json_safe({
        "bench": "puppet",
        "settings": {"drivers": str(drivers), "puppets": [str(p) for p in puppet_paths],
                     "persona_files": persona_files, "size": size,
                     "portraits": [str(p) for p in portraits[0]], "portrait_size": portraits[1],
                     "weights": weights, "max_frames": max_frames,
                     "targets": {k: list(v) for k, v in TARGETS.items()}, "versions": versions()},
        "rows": rows, "summary": summary, "worst": {**worst, "runs": worst_run}, "worst_runs": worst_list,
        "partial": part, "targets_met": ok}), overwrite=True)
    paths.update(sheets)
    if rows and rows[0].get("media"):
        paths.update({k: Path(v) for k, v in rows[0]["media"].items()})
    return {"out": out, "rows": rows, "summary": summary, "worst": worst, "worst_runs": worst_list, "partial": part,
            "files": paths, "targets_met": ok}


def _write_worst_sheet(path: Path, sheet: np.ndarray, row) -> None:
    """The run's 100 % sheet under a white band naming the run, its score and failed measures."""
    import cv2

    from ..io import to_uint8, write_image

    img = to_uint8(sheet)
    band = np.full((22, img.shape[1], 3), 255, np.uint8)
    vals = ", ".join(f"{k} {row.get(k):.2f}" for k in TARGETS if isinstance(row.get(k), (int, float))
                     and np.isfinite(row.get(k)))
    cv2.putText(band, f"{row['run']}  score {row['score']:.2f}  {vals}", (4, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.38,
                (0, 0, 0), 1, cv2.LINE_AA)
    write_image(path, np.concatenate([band, img], 0), overwrite=True)


# --------------------------------------------------------------------------- CLI
def register_bench(bench_subparsers) -> argparse.ArgumentParser:
    """Add the ``puppet`` sub-parser to ``facetex bench``."""
    from ..cli._common import bounded_int, finite_float, positive_int
    from ._common import add_bench_options

    p = bench_subparsers.add_parser(
        "puppet", help="puppetry: every persona x every driver clip (mouth, colour, eyes, sharpness, identity)",
        description="Driver clips drive personas (Tom Hanks §4, §6), every persona with every clip; measured per "
                    "run: the mouth (slope and correlation of the puppet's opening on the driver's), the cheek "
                    "colour (ΔE to the driver's own cheeks), eye openness and blinks, face sharpness, identity "
                    "(closer to the persona than to the driver), the colour step at the composite's edge, lost "
                    "and rejected frames (with a half-out-of-frame check) and flicker. Writes table.md/.csv "
                    "with the worst run of every measure, results.json, per run contact sheets (fitted and "
                    "at 100 %) and zoomed crops, and the 100 % sheets of the three worst runs.")
    add_bench_options(p, "puppet", "data root holding grid/ (driver clips) and lfw/<person>/ (the puppets)")
    p.add_argument("--drivers", metavar="DIR", help="folder of driver videos (default DATA/grid)")
    p.add_argument("--puppets", "--puppet", nargs="+", metavar="PATH", dest="puppets",
                   help="puppet .persona files or photo folders (default every folder of DATA/lfw; a folder is "
                        "built once and cached in --out)")
    p.add_argument("--clips", type=positive_int, help="use only the first N clips")
    p.add_argument("--size", type=bounded_int(32, 4096), default=256, help="longer side of the rendered frames (default 256)")
    p.add_argument("--max-frames", type=positive_int, help="use only the first N frames of each clip")
    p.add_argument("--shape", choices=("collection", "generic"), default="collection",
                   help="puppet average shape: photometric stereo (falls back to generic) or the generic face")
    p.add_argument("--weights", choices=("regional", "global"), default="regional",
                   help="expression weights of the puppet's texture: regional (default) or the paper's global")
    p.add_argument("--weight-smoothing", type=finite_float(0.0, 10.0), metavar="SECONDS",
                   help="temporal coherence of the regional weights (bilateral filter over this many seconds; "
                        "0 = per frame; default: the puppet's default)")
    p.add_argument("--no-partial", action="store_true", help="skip the half-out-of-frame check")
    p.add_argument("--stress", action="store_true",
                   help="also drive every persona with four harder copies of the clips: mirrored and side-lit, "
                        "rotated 14 degrees with the face shrunk, dimmed with sensor noise, with a dark skin "
                        "(written to OUT/stress/)")
    p.add_argument("--portraits", type=positive_int, default=0, metavar="N",
                   help="also drive every persona with N high-resolution still pairs (a closed neutral face, then "
                        "the same person's open smile) from DATA/frl-london, chosen to span skin lightness "
                        "(written to OUT/portraits/)")
    p.add_argument("--portrait-folder", metavar="DIR",
                   help="folder of NNN_neutral / NNN_smiling portrait pairs for --portraits (default DATA/frl-london)")
    p.add_argument("--portrait-size", type=bounded_int(32, 4096), metavar="PX",
                   help="longer side of the portrait runs' frames (default: the portraits' own size)")
    p.add_argument("--resume", action="store_true",
                   help="reuse the runs already in OUT/runs with the same settings (persona file, clip, options)")
    from ..cli._common import add_engine_options

    add_engine_options(p, jobs_help="local: worker processes, one run each (default: the available CPUs); ray: "
                                    "runs in flight")
    p.set_defaults(func=_run)
    return p


def _run(args) -> int:
    from ..cli._common import progress_bar
    from ..io import video_info
    from ._common import data_root, finish_bench

    root = None if (args.drivers and args.puppets and not args.data
                    and (args.portrait_folder or not args.portraits)) else data_root(args.data)
    drivers, puppets = _data_paths(root, args.drivers, args.puppets)
    clips = sorted(f for f in drivers.iterdir() if f.suffix.lower() in (".mpg", ".mp4", ".mov", ".avi", ".mkv")) \
        if drivers.is_dir() else [drivers]
    clips = clips[: args.clips or None]
    total = 0
    runs = clips + ([c for c, _ in stress_sources(clips)] if args.stress and clips else [])
    for c in runs:  # the bar counts evaluated frames (a stress copy has its clip's length)
        try:
            n = video_info(c)["n_frames"]
        except Exception:  # noqa: BLE001 - the run itself reports a bad clip
            n = 0
        total += min(n, args.max_frames) if args.max_frames else n
    total += 2 * HOLD * args.portraits  # at most; fewer when the folder has fewer usable pairs
    total *= len(puppets)
    from ..cli._common import engine_from_args

    with engine_from_args(args, inline_single=True) as engine, \
            progress_bar(total=total or None, desc="bench puppet", unit="frame", disable=args.quiet) as bar:
        res = run_bench_puppet(drivers, puppets=puppets, out=args.out, clips=args.clips, size=args.size,
                               max_frames=args.max_frames, texture_shape=args.shape, weights=args.weights,
                               weight_smoothing=args.weight_smoothing, partial=not args.no_partial,
                               resume=args.resume, stress=args.stress, portraits=args.portraits,
                               portrait_folder=args.portrait_folder, portrait_size=args.portrait_size,
                               data=root, progress=bar, engine=engine)
    table = Path(res["files"]["table_md"]).read_text(encoding="utf-8")
    finish_bench(args, "puppet", res["out"], res["files"],
                 inputs={"drivers": drivers, **{f"puppet{k}": p for k, p in enumerate(puppets)}},
                 settings={"drivers": str(drivers), "puppets": [str(p) for p in puppets]},
                 summary={"summary": res["summary"], "worst": res["worst"], "worst_runs": res["worst_runs"],
                          "partial": res["partial"], "targets_met": res["targets_met"]},
                 table=table)
    return 0


def run_bench_puppet_cli(argv: Sequence[str] | None = None) -> int:
    """Stand-alone entry (``python -m facetex.bench.puppet``)."""
    ap = argparse.ArgumentParser(prog="facetex bench")
    register_bench(ap.add_subparsers(dest="bench", required=True))
    args = ap.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    raise SystemExit(run_bench_puppet_cli())
