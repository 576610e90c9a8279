"""The three batch workloads: their items (what to compute, where it goes) and the function a
worker runs for one item.

Each worker function calls the public API (:func:`facetex.transfer_with_info`,
:func:`facetex.build_persona`, :func:`facetex.puppeteer`) exactly as a user's script would, and
commits the output together with its provenance sidecar (``OUT.json``, the same record the
single-item command writes) through :func:`facetex.io.write_files`: both files or neither,
never replacing an existing file.
"""

from __future__ import annotations

import csv
import hashlib
import io
import os
import re
import time
from pathlib import Path
from typing import Sequence

from ..errors import BadInputError, OutputError
from ._run import Item
from ._store import check_remote_input, is_url, join, list_files, name_of, parent_of, read_input_bytes
from .engines import Resources

__all__ = ["transfer_items", "persona_items", "puppet_items", "read_pairs_csv", "pairs_from_folders",
           "run_transfer_item", "run_persona_item", "run_puppet_item", "item_key", "folder_settings",
           "TRANSFER_COLUMNS", "DRIVER_EXTENSIONS"]

TRANSFER_COLUMNS = ("content", "style", "method", "preset", "seed")
DRIVER_EXTENSIONS = (".mp4", ".mov", ".m4v", ".mkv", ".avi", ".mpg", ".mpeg", ".webm")
_IMAGE_EXTS = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".webp", ".bmp")


# per kind: the config keys every item of a run shares and its output's name does not show
_FOLDER_SETTINGS = {"transfer": ("size", "iters", "device"), "persona": ("min_photos", "allow_mixed"),
                    "puppet": ("size", "mode", "side_by_side", "lighting", "texture", "weights", "max_frames")}


def folder_settings(items: Sequence[Item]) -> dict:
    """The settings of a run of ``items`` (of one kind) that its output folder must keep (see
    :func:`facetex.batch.run_batch`'s ``settings``)."""
    kind = items[0].kind
    return {"kind": kind, **{k: items[0].config.get(k) for k in _FOLDER_SETTINGS.get(kind, ())}}


def memory_mb(kind: str, config: dict) -> float:
    """The peak resident memory (MB) of one item of ``kind``, for Ray's ``memory=`` request.
    Transfer, measured on one thread (2026-12-02; peak RSS of a fresh process): 520 MB at
    ``--size`` 96, 578 at 256, 774 at 512, 789 with the default preset (a 384 px crop pasted
    back at full resolution): about 510 + size² / 1000. Persona builds and puppet renders
    depend on the photos and the clip: a first request of 1.5 GB, after which the run asks
    for the largest peak it measured (see :func:`facetex.batch.engines.ray_task_options`)."""
    if kind == "transfer":
        size = config.get("size")
        return 800.0 if not size else 510.0 + float(size) ** 2 / 1000.0
    return 1500.0


def item_key(*parts) -> str:
    """A file-name-safe item key (letters, digits, ``_``, ``-``; no dots) from ``parts`` joined by ``__``."""
    return "__".join(re.sub(r"[^A-Za-z0-9_-]+", "-", str(p)).strip("-") or "x" for p in parts)


def _commit(files: dict, inputs=(), batch=None) -> str | None:
    """Write ``files`` ({output: ..., sidecar: ...}, bytes or callable(tmp)) as one (exclusive
    creates), the sidecar moved into place first: a commit cut short leaves a sidecar naming
    its item, which the next run removes, never an output without a sidecar, which it would
    have to take for a user's file. When all of them already exist (another run computed the
    item after its claim expired) that is not an error: returns a note instead.

    With ``batch["replace"]`` (the item's inputs changed since its files were made) the files
    replace the old ones, each by a rename, the output first and the sidecar, which names the
    new input digests, last: a commit cut short leaves the old digests, so the next run redoes it."""
    from ..io import write_files

    if isinstance(batch, dict) and batch.get("replace"):
        write_files(files, overwrite=True, inputs=inputs)
        return None
    try:
        write_files(files, overwrite=False, inputs=inputs, reverse_commit=True)
    except OutputError:
        if all(os.path.lexists(p) for p in files):
            return "written by another run"
        raise
    return None


def _provenance(command: str, payload: dict, **kw) -> dict:
    import sys

    from .._provenance import provenance

    torch = sys.modules.get("torch")  # outputs are the same bytes for the same seeds and threads (README)
    threads = torch.get_num_threads() if torch is not None else None
    return provenance(command=command, argv=payload.get("argv"), batch=payload.get("batch"), threads=threads, **kw)


# ------------------------------------------------------------------------------ transfer
def run_transfer_item(p: dict) -> dict:
    """One transfer: ``facetex.transfer_with_info(content, style, ...)`` -> OUT.png + OUT.png.json."""
    import facetex
    from ..io import encode_image, encode_json

    t0 = time.perf_counter()
    options = {k: p[k] for k in ("size", "iters") if p.get(k) is not None}
    image, info = facetex.transfer_with_info(p["content"], p["style"], method=p["method"], preset=p["preset"],
                                             seed=int(p["seed"]), device=p["device"], **options)
    info.pop("images", None)
    info.setdefault("timings", {})["wall_s"] = time.perf_counter() - t0
    out = p["output"]
    sidecar = f"{out}.json"
    record = _provenance("batch transfer", p, seed=int(p["seed"]),
                         inputs={"content": p["content"], "style": p["style"]},
                         params={**(info.get("params") or {}), "method": p["method"], "preset": p["preset"],
                                 "device": p["device"], "command_line_options": options},
                         outputs=[out], result=info)
    note = _commit({out: encode_image(out, image), sidecar: encode_json(record)}, inputs=[p["content"], p["style"]],
                   batch=p.get("batch"))
    return {"outputs": [out, sidecar], "note": note, "timings": info.get("timings")}


def read_pairs_csv(path) -> list[dict]:
    """Rows of a pairs CSV: a header with ``content`` and ``style`` (and optionally ``method``,
    ``preset``, ``seed``), then one pair per line. Relative paths are relative to the CSV's
    folder. One-line errors name the file and line."""
    from ..io import check_input_file

    remote = is_url(path)
    if not remote:
        path = check_input_file(path, BadInputError, what="pairs CSV file")
    try:
        text = read_input_bytes(str(path)).decode("utf-8-sig") if remote else path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise BadInputError("not a UTF-8 text file: give a CSV file with columns content,style", path=path) from None
    reader = csv.DictReader(io.StringIO(text, newline=""))  # a quoted field may hold a line break
    cols = [c.strip().lower() for c in (reader.fieldnames or [])]
    if "content" not in cols or "style" not in cols:
        raise BadInputError(f"the first line must name the columns: content,style[,method,preset,seed] (got "
                            f"{','.join(cols) or 'nothing'})", path=path)
    unknown = [c for c in cols if c not in TRANSFER_COLUMNS]
    if unknown:
        raise BadInputError(f"unknown column {unknown[0]!r}: the columns are {', '.join(TRANSFER_COLUMNS)}", path=path)
    reader.fieldnames = cols
    rows = []
    for row in reader:  # the line the record starts on (a quoted field may hold line breaks)
        line = reader.line_num - sum(v.count("\n") for v in row.values() if isinstance(v, str))
        r = {k: (v or "").strip() for k, v in row.items() if k is not None}
        if not any(r.values()):
            continue
        if None in row:
            raise BadInputError(f"line {line} has more fields than the header", path=path)
        for k in ("content", "style"):
            if not r.get(k):
                raise BadInputError(f"line {line}: the {k} image is missing", path=path)
            if is_url(r[k]):
                continue
            p = Path(r[k]).expanduser()
            if p.is_absolute():
                r[k] = str(p)
            else:  # relative to the CSV (a URL's folder too)
                r[k] = join(parent_of(path), r[k]) if remote else str(path.parent / p)
        r["source"] = f"{path}:{line}"
        rows.append(r)
    if not rows:
        raise BadInputError("no pairs in the file (only a header?)", path=path)
    return rows


def _folder_files(folder, what: str, exts: Sequence[str]) -> list[str]:
    """The files of ``folder`` (a local folder or a URL) with one of ``exts``, not hidden, sorted."""
    from ..io import check_input_dir

    if is_url(folder):
        files = [u for u in list_files(str(folder)) if os.path.splitext(name_of(u))[1].lower() in exts
                 and not name_of(u).startswith(".")]
    else:
        d = check_input_dir(folder, BadInputError, what=what)
        files = sorted(str(p) for p in d.iterdir() if p.is_file() and p.suffix.lower() in exts
                       and not p.name.startswith("."))
    return files


def _stem(path) -> str:
    return os.path.splitext(name_of(path))[0]


def _absolute(path) -> str:
    return str(path) if is_url(path) else str(Path(path).resolve())


def _output(out, name: str) -> str:
    return join(str(out).rstrip("/"), name) if is_url(out) else str(Path(out).resolve() / name)


def _images(folder, what: str) -> list[str]:
    files = _folder_files(folder, what, _IMAGE_EXTS)
    if not files:
        raise BadInputError(f"no images ({', '.join(_IMAGE_EXTS)}) in the {what}", path=folder)
    return files


def pairs_from_folders(contents, styles, pairs: int | str = "all", *, seed: int = 0) -> list[dict]:
    """(content, style) rows: every image of ``contents`` with every image of ``styles`` (not
    with itself), or ``pairs`` of them ranked by a hash of the two names and ``seed`` (adding
    images keeps the other pairs' order)."""
    cs, ss = _images(contents, "contents folder"), _images(styles, "styles folder")
    combos = [(c, s) for c in cs for s in ss if _absolute(c) != _absolute(s)]
    if not combos:
        raise BadInputError("no (content, style) pair of two different images", path=contents)
    if pairs != "all":
        n = int(pairs)
        if n < 1:
            raise BadInputError(f"--pairs must be 'all' or at least 1, not {pairs}")

        def rank(cs):
            return hashlib.sha256(f"{int(seed)}\0{name_of(cs[0])}\0{name_of(cs[1])}".encode()).hexdigest()

        combos = sorted(combos, key=rank)[:n]
    return [{"content": str(c), "style": str(s), "source": f"{name_of(c)} x {name_of(s)}"} for c, s in combos]


def transfer_items(rows: Sequence[dict], out, *, method: str = "facetex", preset: str = "default", seed: int = 0,
                   size: int | None = None, iters=None, device: str = "cpu", cpus: int | None = None,
                   argv=None) -> list[Item]:
    """Items of ``facetex batch transfer``: per row ``OUT/<content>__<style>__<method>[__<preset>]
    [__seed<N>].png`` (+ ``.png.json``). A row's method / preset / seed override the defaults."""
    from ..io import check_input_file
    from ..transfer.methods import METHODS, PRESETS

    items = []
    checked: set[str] = set()
    for r in rows:
        where = r.get("source", "")
        m = (r.get("method") or method).lower()
        pr = (r.get("preset") or preset).lower()
        if m not in METHODS:
            raise BadInputError(f"{where}: unknown method {m!r}: use one of {', '.join(METHODS)}")
        if pr not in PRESETS:
            raise BadInputError(f"{where}: unknown preset {pr!r}: use one of {', '.join(PRESETS)}")
        try:
            sd = int(r["seed"]) if r.get("seed") not in (None, "") else int(seed)
        except ValueError:
            raise BadInputError(f"{where}: seed must be an integer, not {r['seed']!r}") from None
        for k in ("content", "style"):
            if r[k] not in checked:
                try:
                    if is_url(r[k]):
                        check_remote_input(r[k], f"{k} image")
                    else:
                        check_input_file(r[k], BadInputError, what=f"{k} image")
                except BadInputError as e:
                    raise type(e)(f"{e.message} ({where})" if where else e.message, path=e.path) from None
                checked.add(r[k])
        content, style = _absolute(r["content"]), _absolute(r["style"])
        parts = [_stem(content), _stem(style), m] + ([pr] if pr != "default" else []) + \
            ([f"seed{sd}"] if sd != 0 else [])
        key = item_key(*parts)
        output = _output(out, f"{key}.png")
        config = {"content": content, "style": style, "method": m, "preset": pr, "seed": sd, "size": size,
                  "iters": list(iters) if iters is not None else None, "device": device}
        payload = dict(config, output=output, argv=argv, source=where)
        items.append(Item(key, "transfer", run_transfer_item, payload, (output, f"{output}.json"), config,
                          Resources(cpus=cpus or 0, gpus=1.0 if device.startswith("cuda") else 0.0,
                                    memory_mb=memory_mb("transfer", config)),
                          inputs=(content, style)))
    return items


# ------------------------------------------------------------------------------- persona
def run_persona_item(p: dict) -> dict:
    """One persona: ``facetex.build_persona(folder, ...)`` -> NAME.persona + NAME.persona.json."""
    import facetex
    from ..io import encode_json

    t0 = time.perf_counter()
    jobs = int(p.get("jobs") or os.environ.get("OMP_NUM_THREADS") or 1)  # the item's CPU budget
    persona = facetex.build_persona(p["photo_dir"], jobs=jobs, min_photos=int(p["min_photos"]),
                                    allow_mixed=bool(p["allow_mixed"]))
    out = p["output"]
    record = _provenance("batch persona", p, inputs={"photo_dir": p["photo_dir"]},
                         params={"jobs": jobs, "min_photos": p["min_photos"], "allow_mixed": p["allow_mixed"],
                                 "persona_params": persona.params},
                         outputs=[out], photos_used=len(persona), skipped=persona.skipped,
                         seconds=time.perf_counter() - t0)
    note = _commit({out: lambda tmp: persona.save(tmp, overwrite=True), f"{out}.json": encode_json(record)},
                   batch=p.get("batch"))
    return {"outputs": [out, f"{out}.json"], "note": note, "photos_used": len(persona),
            "skipped": len(persona.skipped)}


def persona_items(people_dir, out, *, min_photos: int = 10, allow_mixed: bool = False, cpus: int | None = None,
                  argv=None) -> tuple[list[Item], list[str]]:
    """Items of ``facetex batch persona``: one ``OUT/<name>.persona`` per subfolder of
    ``people_dir`` that holds photos. Returns (items, names of subfolders left out)."""
    from ..io import check_input_dir

    root = check_input_dir(people_dir, BadInputError, what="people folder")
    items, ignored = [], []
    for d in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
        if not any(f.is_file() and f.suffix.lower() in _IMAGE_EXTS for f in d.iterdir()):
            ignored.append(d.name)
            continue
        key = item_key(d.name)
        output = _output(out, f"{key}.persona")
        config = {"photo_dir": str(d.resolve()), "min_photos": int(min_photos), "allow_mixed": bool(allow_mixed)}
        payload = dict(config, output=output, jobs=cpus, argv=argv, source=str(d))
        items.append(Item(key, "persona", run_persona_item, payload, (output, f"{output}.json"), config,
                          Resources(cpus=cpus or 0, memory_mb=memory_mb("persona", config)),
                          inputs=(config["photo_dir"],)))
    if not items:
        raise BadInputError("no subfolder with photos: give a folder with one subfolder of photos per person",
                            path=root)
    return items, ignored


# -------------------------------------------------------------------------------- puppet
def run_puppet_item(p: dict) -> dict:
    """One puppet video: ``facetex.puppeteer(driver, persona, ...)`` -> OUT.mp4 + OUT.mp4.json."""
    import facetex
    from ..io import encode_json

    out = p["output"]
    report: dict = {}
    opts = {k: p[k] for k in ("side_by_side", "size", "mode", "lighting", "texture", "weights", "max_frames")}

    def video(tmp):
        report.update(facetex.puppeteer(p["driver"], p["puppet"], tmp, overwrite=True, **opts))
        report["output"] = out

    def sidecar(tmp):
        Path(tmp).write_bytes(encode_json(_provenance(
            "batch puppet", p, inputs={"driver": p["driver"], "puppet": p["puppet"]}, params=opts,
            outputs=[out], result=report)))

    note = _commit({out: video, f"{out}.json": sidecar}, inputs=[p["driver"], p["puppet"]], batch=p.get("batch"))
    return {"outputs": [out, f"{out}.json"], "note": note, "frames": report.get("frames"),
            "lost_frames": report.get("lost_frames")}


def puppet_items(drivers, puppets, out, *, size: int | None = None, mode: str = "composite",
                 side_by_side: bool = False, lighting: str = "stats", texture: str = "ours",
                 weights: str = "regional", max_frames: int | None = None, cpus: int | None = None,
                 argv=None) -> list[Item]:
    """Items of ``facetex batch puppet``: every driver video of ``drivers`` with every
    ``.persona`` of ``puppets`` -> ``OUT/<driver>__<puppet>.mp4``."""
    clips = _folder_files(drivers, "drivers folder", DRIVER_EXTENSIONS)
    if not clips:
        raise BadInputError(f"no driver videos ({', '.join(DRIVER_EXTENSIONS)})", path=drivers)
    personas = _folder_files(puppets, "puppets folder", (".persona",))
    if not personas:
        raise BadInputError("no .persona files (build them with `facetex batch persona`)", path=puppets)
    items = []
    for c in clips:
        for pp in personas:
            key = item_key(_stem(c), _stem(pp))
            output = _output(out, f"{key}.mp4")
            config = {"driver": _absolute(c), "puppet": _absolute(pp), "size": size, "mode": mode,
                      "side_by_side": bool(side_by_side), "lighting": lighting, "texture": texture,
                      "weights": weights, "max_frames": max_frames}
            payload = dict(config, output=output, argv=argv, source=f"{name_of(c)} x {name_of(pp)}")
            items.append(Item(key, "puppet", run_puppet_item, payload, (output, f"{output}.json"), config,
                              Resources(cpus=cpus or 0, memory_mb=memory_mb("puppet", config)),
                              inputs=(config["driver"], config["puppet"])))
    return items
