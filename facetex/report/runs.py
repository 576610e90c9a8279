"""Reading run folders: what a benchmark, the demo or a set of single runs left behind.

A :class:`Run` is the part of a folder a report shows: settings and provenance, the
Markdown tables the run wrote, per-item metrics (one record per pair and method, or per
target, or per clip), the images to compare and the figures. Layouts understood:

- ``facetex bench transfer``: ``results.json`` (``pairs.json`` before 2026-12; + ``images/``, ``results/``,
  ``table.md``, ``zoom.png``, ``run.json``);
- ``facetex bench persona``: ``results.json`` + ``per_target.csv`` + ``table.md`` (+ grid and zoom sheets);
- ``facetex bench puppet``: ``results.json`` + ``table.md`` (+ contact sheet);

A bench's ``results.json`` names its bench (``"bench": "persona"``); older folders (persona
``summary.json``, puppet ``results.json`` without the key) are recognised by their files.
- ``facetex demo``: ``summary.json`` + ``transfer_<method>.png``;
- any folder of outputs with ``*.json`` sidecars (``facetex transfer -o DIR/x.png``).

A run folder is data from anywhere, and a report is shared: every file is read through a
:class:`ReadGuard`, which lets through only regular files (no symlinks, FIFOs or devices) whose
resolved paths are inside the run folders given (or folders the user adds, such as a bench's
``--data``, and facetex's own samples); the others are skipped and listed.
"""

from __future__ import annotations

import csv
import io
import math
import os
import stat
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from .._methods import METHOD_ORDER, PERSONA_ORDER, method_sort_key, method_title
from .._schema import OBJECT, nullable, parse_json
from ..errors import BadInputError
from ..io import read_regular

__all__ = ["Run", "Item", "load_run", "load_runs", "ReadGuard", "METHOD_ORDER"]

_IMAGE_EXT = (".png", ".jpg", ".jpeg", ".webp", ".tif", ".tiff")

# The shapes of the JSON files a report reads (the fields it uses; others are free).
_NAME = {"type": ["string", "number"]}
_METRICS = nullable({"type": "object"})
_BENCH_TRANSFER = {"type": "object", "properties": {
    "settings": OBJECT,
    "paper_table1": nullable({"type": "object", "additionalProperties": OBJECT}),
    "pairs": {"type": "array", "items": {"type": "object", "required": ["content", "style"], "properties": {
        "content": _NAME, "style": _NAME, "content_path": {"type": "string"}, "style_path": {"type": "string"},
        "results": {"type": "object", "additionalProperties": {"type": "object", "properties": {
            "image": nullable({"type": "string"}), "metrics": _METRICS}}}}}}}}
_BENCH_PUPPET = {"type": "object", "properties": {
    "settings": OBJECT,
    "rows": {"type": "array", "items": {"type": "object", "properties": {
        "run": nullable(_NAME), "clip": nullable(_NAME),
        "media": nullable({"type": "object", "properties": {"contact_sheet": {"type": "string"}}})}}}}}
_DEMO = {"type": "object", "properties": {
    "inputs": {"type": "object", "properties": {"content": {"type": "string"}, "style": {"type": "string"}}},
    "transfers": nullable({"type": "object", "additionalProperties": {"type": "object", "properties": {
        "metrics": _METRICS}}})}}
_INPUT = nullable({"type": "object", "properties": {"path": nullable({"type": "string"})}})
_SIDECAR = {"type": "object", "properties": {
    "inputs": nullable({"type": "object", "properties": {"content": _INPUT, "style": _INPUT}}),
    "params": nullable({"type": "object", "properties": {"method": nullable({"type": "string"})}}),
    "metrics": _METRICS,
    "result": nullable({"type": "object", "properties": {"timings": nullable({"type": "object"})}})}}
_RUN_JSON = {"type": "object", "properties": {
    "command": {"type": "string"}, "command_line": {"type": "string"}, "created_utc": {"type": "string"},
    "versions": nullable({"type": "object"}), "params": nullable({"type": "object"})}}


@dataclass
class Item:
    """One compared unit: a content/style pair (transfer), a held-out photo (persona), a clip."""

    key: str
    label: str
    #: name -> image path, in display order ("style", "content", then one per method)
    images: dict[str, Path] = field(default_factory=dict)
    #: method -> metric -> value
    metrics: dict[str, dict[str, float]] = field(default_factory=dict)
    #: images shown only in zoom crops, placed at the content's landmarks (e.g. the pre-warped style)
    aligned: dict[str, Path] = field(default_factory=dict)
    #: files of this item a reader may open (label -> path), linked from the report
    files: dict[str, Path] = field(default_factory=dict)


@dataclass
class Run:
    """What a report shows of one run folder."""

    path: Path
    name: str
    kind: str  # "bench transfer" | "bench persona" | "bench puppet" | "demo" | "outputs"
    settings: dict = field(default_factory=dict)
    provenance: dict | None = None
    tables: dict[str, str] = field(default_factory=dict)  # file name -> Markdown text
    items: list[Item] = field(default_factory=list)
    figures: list[Path] = field(default_factory=list)
    #: method -> metric -> reference value from the paper (other data)
    paper: dict[str, dict[str, float]] = field(default_factory=dict)
    paper_source: str = ""
    sidecars: dict[str, dict] = field(default_factory=dict)  # relative path -> sidecar record
    #: files named or found in the run folders that were not read (see ReadGuard)
    skipped: list[str] = field(default_factory=list)
    #: the order methods are shown in (the transfer methods' one order; persona: Fig. 5's rows)
    method_order: tuple[str, ...] = METHOD_ORDER
    #: what else a bench wrote that a report shows (puppet: targets, worst runs)
    extra: dict = field(default_factory=dict)

    @property
    def methods(self) -> list[str]:
        seen: list[str] = []
        for it in self.items:
            for m in it.metrics:
                if m not in seen:
                    seen.append(m)
        return sorted(seen, key=lambda m: method_sort_key(m, self.method_order))

    @property
    def metric_names(self) -> list[str]:
        seen: list[str] = []
        for it in self.items:
            for vals in it.metrics.values():
                for k, v in vals.items():
                    if k not in seen and isinstance(v, (int, float)) and not isinstance(v, bool):
                        seen.append(k)
        return seen

    def values(self, method: str, metric: str) -> list[float]:
        """The metric of ``method`` over the items (NaN where missing)."""
        out = []
        for it in self.items:
            v = it.metrics.get(method, {}).get(metric)
            out.append(float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else math.nan)
        return out


class ReadGuard:
    """What a report may read: regular files (no symlinks, FIFOs or devices) whose resolved
    paths are inside ``roots``. Anything else a run folder holds or names is not read but
    remembered in ``skipped``."""

    def __init__(self, roots=(), *, images: bool = True):
        from .._resources import sample_path

        self.roots = [Path(r).resolve() for r in (*roots, sample_path())]
        self.skipped: list[str] = []
        self.images = images  # False: images are not looked at (``facetex compare``)

    def image(self, path) -> bool:
        """Whether the image ``path`` is shown (see :meth:`allows`)."""
        return self.images and self.allows(path)

    def allows(self, path) -> bool:
        """Whether ``path`` may be read (an absent path is not, and is not "skipped")."""
        p = Path(path)
        try:
            st = os.lstat(p)
        except (OSError, ValueError):
            return False
        if stat.S_ISREG(st.st_mode) and any(p.resolve().is_relative_to(r) for r in self.roots):
            return True
        if str(p) not in self.skipped:
            self.skipped.append(str(p))
        return False

    def read_bytes(self, path) -> bytes | None:
        """The bytes of ``path``, or None when it may not be read or is absent."""
        if not self.allows(path):
            return None
        try:
            return read_regular(path)
        except OSError:  # replaced meanwhile (by a FIFO, a link): not ours to read
            self.skipped.append(str(path))
            return None

    def read_text(self, path, what: str = "text file") -> str | None:
        """The UTF-8 text of ``path`` (None: see :meth:`read_bytes`)."""
        data = self.read_bytes(path)
        try:
            return None if data is None else data.decode("utf-8")
        except UnicodeDecodeError:
            raise BadInputError(f"not a UTF-8 text file: not a {what}", path=path) from None

    def read_json(self, path, schema: dict, what: str):
        """The JSON of ``path`` checked against ``schema`` (None: see :meth:`read_bytes`)."""
        data = self.read_bytes(path)
        return None if data is None else parse_json(data, schema, path=path, what=what)


def _read_json(path: Path, guard: ReadGuard, schema: dict, what: str):
    value = guard.read_json(path, schema, what)
    if value is None:
        raise BadInputError("not a regular file inside the run folders: not read", path=path)
    return value


def _tables(folder: Path, guard: ReadGuard) -> dict[str, str]:
    out = {}
    for p in sorted(folder.glob("table*.md")):
        text = guard.read_text(p, "Markdown table")
        if text is not None:
            out[p.name] = text
    return out


def _figures(folder: Path, guard: ReadGuard) -> list[Path]:
    names = ("grid", "scatter", "figure", "contact", "zoom", "teeth")
    return sorted(p for p in folder.iterdir() if p.suffix.lower() == ".png" and p.stem.startswith(names)
                  and guard.image(p))


def _bench_json(folder: Path, guard: ReadGuard) -> tuple[str | None, Path | None]:
    """(bench name, its JSON file) of a bench run folder, or (None, None)."""
    res = folder / "results.json"
    if guard.allows(res):
        bench = guard.read_json(res, OBJECT, "bench results file").get("bench")
        if bench in ("transfer", "persona", "puppet"):
            return bench, res
    if guard.allows(folder / "pairs.json"):
        return "transfer", folder / "pairs.json"
    if guard.allows(res) and guard.allows(folder / "table.md"):
        return "puppet", res
    if guard.allows(folder / "summary.json") and guard.allows(folder / "per_target.csv"):
        return "persona", folder / "summary.json"
    return None, None


def _load_bench_transfer(folder: Path, run: Run, path: Path, guard: ReadGuard) -> None:
    pj = _read_json(path, guard, _BENCH_TRANSFER, "bench transfer results file")
    run.kind = "bench transfer"
    run.settings = dict(pj.get("settings", {}))
    run.paper = {m: dict(v) for m, v in (pj.get("paper_table1") or {}).items()}
    run.paper_source = "FaceTex Table 1 (Kaur, Zhang & Dana 2017): 5 pairs of other head portraits"
    for p in pj.get("pairs", []):
        c, s = p["content"], p["style"]
        it = Item(key=f"{c}__{s}", label=f"content {c} / style {s}")
        for name, key in (("style", "style_path"), ("content", "content_path")):
            path = Path(p.get(key, ""))
            if p.get(key) and guard.image(path):
                it.images[name] = path
        results = p.get("results", {})
        for m in sorted(results, key=method_sort_key):
            r = results[m]
            if r.get("image") and guard.image(folder / r["image"]):
                it.images[m] = folder / r["image"]
                it.files[method_title(m)] = folder / r["image"]
            res_file = folder / "results" / f"{c}__{s}__{m}.json"
            if os.path.lexists(res_file):
                it.files[f"{method_title(m)} scores"] = res_file
            it.metrics[m] = {k: v for k, v in (r.get("metrics") or {}).items()}
            if isinstance(r.get("wall_s"), (int, float)):
                it.metrics[m]["time_s"] = float(r["wall_s"])
        prewarp = folder / "images" / f"{c}__{s}__prewarp.png"
        if os.path.lexists(prewarp) and guard.image(prewarp):
            it.aligned["style, pre-warped"] = prewarp
        run.items.append(it)
    for sc in sorted((folder / "images").glob("*.json")):
        rec = guard.read_json(sc, _SIDECAR, "sidecar")
        if rec is not None:
            run.sidecars[f"images/{sc.name}"] = rec


def _load_bench_persona(folder: Path, run: Run, path: Path, guard: ReadGuard) -> None:
    summary = _read_json(path, guard, OBJECT, "bench persona summary")
    run.kind = "bench persona"
    run.method_order = PERSONA_ORDER  # Tom Hanks Fig. 5: static, weighted, prewarp, paper, ours
    run.settings = {k: v for k, v in summary.items() if k not in ("rows", "skipped", "held_out", "teeth", "bench", "mouth_gain_by_expression")}
    text = guard.read_text(folder / "per_target.csv", "CSV file")
    if text is not None:
        with io.StringIO(text, newline="") as fh:
            for row in csv.DictReader(fh):
                it = Item(key=row.get("file", ""), label=row.get("file", ""))
                for k, v in row.items():  # "<row>_<metric>", e.g. ours_mouth_ssim; px_<region>: mask sizes
                    if not isinstance(k, str) or "_" not in k or k == "file" or k.startswith("px_"):
                        continue
                    method, metric = k.split("_", 1)
                    try:
                        it.metrics.setdefault(method, {})[metric] = float(v)
                    except (TypeError, ValueError):
                        pass
                run.items.append(it)


def _load_bench_puppet(folder: Path, run: Run, path: Path, guard: ReadGuard) -> None:
    res = _read_json(path, guard, _BENCH_PUPPET, "bench puppet results file")
    run.kind = "bench puppet"
    run.settings = dict(res.get("settings", {}))
    run.extra = {"targets": dict(run.settings.get("targets") or {}),
                 "worst_runs": [w for w in (res.get("worst_runs") or []) if isinstance(w, dict)],
                 "targets_met": dict(res.get("targets_met") or {})}
    # the worst runs' sheets the bench wrote, read like every other file (inside the run folders only)
    run.extra["worst_sheets"] = [(w, Path(w["sheet"])) for w in run.extra["worst_runs"]
                                 if isinstance(w.get("sheet"), str) and w["sheet"] and guard.image(Path(w["sheet"]))]
    for r in res.get("rows", []):
        run_key = r.get("run") or r.get("clip")  # "<persona>/<clip>"; older runs: the clip
        it = Item(key=str(run_key), label=f"run {run_key}" if r.get("run") else f"clip {run_key}")
        it.metrics["puppet"] = {k: v for k, v in r.items() if isinstance(v, (int, float)) and not isinstance(v, bool)
                                and k != "score"}
        if isinstance(r.get("score"), (int, float)):
            it.metrics["puppet"]["fail_score"] = float(r["score"])  # 0: every target met
        media = r.get("media") or {}
        sheet = Path(media.get("contact_sheet", ""))
        if media.get("contact_sheet") and guard.image(sheet):
            it.images["contact sheet"] = sheet
        for label, key in (("contact sheet", "contact_sheet"), ("side by side", "mp4"), ("zoom", "zoom")):
            if isinstance(media.get(key), str) and media[key]:
                it.files[label] = Path(media[key])
        run.items.append(it)


def _load_demo(folder: Path, run: Run, guard: ReadGuard) -> None:
    from .._resources import sample_path

    summary = _read_json(folder / "summary.json", guard, _DEMO, "demo summary")
    run.kind = "demo"
    run.settings = {k: v for k, v in summary.items() if k not in ("transfers",)}
    ins = summary.get("inputs", {})
    it = Item(key="demo", label=f"content {ins.get('content')} / style {ins.get('style')}")
    for name in ("style", "content"):
        p = sample_path(ins.get(name, "")) if ins.get(name) else None
        if p is not None and guard.image(p):
            it.images[name] = p
    for m, t in (summary.get("transfers") or {}).items():
        img = folder / f"transfer_{m}.png"
        if guard.image(img):
            it.images[m] = img
        it.metrics[m] = {**(t.get("metrics") or {}), "time_s": t.get("seconds")}
    run.items.append(it)


def _load_outputs(folder: Path, run: Run, guard: ReadGuard) -> None:
    """A folder of outputs with sidecars: one item per output image whose sidecar names a
    content and a style (``facetex transfer``), grouped by (content, style)."""
    run.kind = "outputs"
    groups: dict[tuple, Item] = {}
    for img in sorted(p for p in folder.iterdir() if p.suffix.lower() in _IMAGE_EXT):
        sc = img.with_name(img.name + ".json")
        if not os.path.lexists(sc) or not guard.allows(img):
            continue
        rec = guard.read_json(sc, _SIDECAR, "sidecar")
        if rec is None:
            continue
        run.sidecars[sc.name] = rec
        ins = rec.get("inputs") or {}
        c, s = (ins.get("content") or {}).get("path"), (ins.get("style") or {}).get("path")
        key = (c, s)
        if key not in groups:
            groups[key] = Item(key=f"{Path(c).stem if c else '?'}__{Path(s).stem if s else '?'}",
                               label=f"content {Path(c).name if c else '?'} / style {Path(s).name if s else '?'}")
            for name, p in (("style", s), ("content", c)):
                if p and guard.image(p):
                    groups[key].images[name] = Path(p)
        method = (rec.get("params") or {}).get("method") or img.stem
        label = method if method not in groups[key].images else img.stem
        groups[key].images[label] = img
        res = rec.get("metrics") or {}
        timings = (rec.get("result") or {}).get("timings") or {}
        groups[key].metrics[label] = {**{k: v for k, v in res.items() if isinstance(v, (int, float))},
                                      **({"time_s": timings["total_s"]} if "total_s" in timings else {})}
    run.items.extend(groups.values())


def load_run(path, guard: ReadGuard | None = None) -> Run:
    """Read one run folder (see the module docstring for the layouts), through ``guard``
    (default: one that reads inside this folder only).

    Raises BadInputError naming the folder when it is missing or holds nothing a report can show."""
    from ..io import check_input_dir

    folder = check_input_dir(path, BadInputError, what="run folder")
    guard = guard or ReadGuard([folder])
    run = Run(path=folder, name=folder.resolve().name, kind="", skipped=guard.skipped)
    run.provenance = guard.read_json(folder / "run.json", _RUN_JSON, "run record (run.json)")
    bench, bench_json = _bench_json(folder, guard)
    if bench is not None:
        {"transfer": _load_bench_transfer, "persona": _load_bench_persona,
         "puppet": _load_bench_puppet}[bench](folder, run, bench_json, guard)
    elif guard.allows(folder / "summary.json") and any(folder.glob("transfer_*.png")):
        _load_demo(folder, run, guard)
    else:
        _load_outputs(folder, run, guard)
    run.tables = _tables(folder, guard)
    run.figures = _figures(folder, guard)
    if not run.items and not run.tables:
        raise BadInputError("nothing to report: not a run folder of facetex bench / demo, and no output images "
                            "with .json sidecars", path=folder)
    return run


def load_runs(paths, *, also=(), images: bool = True) -> list[Run]:
    """:func:`load_run` of each folder, all through one :class:`ReadGuard` of those folders and
    ``also`` (folders the user lets the report read, e.g. a bench's ``--data``); one warning
    lists the files skipped. ``images=False``: metrics only (no image is looked at)."""
    guard = ReadGuard([*paths, *also], images=images)
    runs = [load_run(p, guard) for p in paths]
    if guard.skipped:
        shown = ", ".join(guard.skipped[:5]) + (f" and {len(guard.skipped) - 5} more" if len(guard.skipped) > 5 else "")
        warnings.warn(f"skipped {len(guard.skipped)} file(s) that are not regular files inside the run folders "
                      f"(links, FIFOs, devices, or elsewhere): {shown}", stacklevel=2)
    return runs
