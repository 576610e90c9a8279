"""The state of a batch folder: one record per item, and ``manifest.jsonl`` built from them.

Layout of an output folder ``DIR``::

    DIR/<item outputs>            e.g. a__b__facetex.png + a__b__facetex.png.json
    DIR/manifest.jsonl            one JSON line per item: state, host, time, error, ...
    DIR/.facetex-batch/items/     <key>.json: the item's current record (written by its claim holder)
    DIR/.facetex-batch/claims/    <key>.<generation>: who computes the item now (see _claims.py)
    DIR/.facetex-batch/runs/      <run>.json: each run's command line, engine and summary

Only the process holding an item's claim writes its record; every write is atomic (temporary
file, then rename), so a reader on any host sees the old record or the new one. The manifest
is a snapshot rewritten atomically from the records (never appended to: appends are not
atomic on NFS), sorted by item key.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path

from .._schema import OBJECT, check_shape, nullable, parse_json
from ..errors import OutputError
from ..io import read_regular, write_json

__all__ = ["BatchState", "config_hash", "utc_now", "read_record", "STATES"]

STATES = ("pending", "running", "done", "failed")
_INTERNAL = ".facetex-batch"
_STR = nullable({"type": "string"})
RECORD = {"type": "object", "properties": {
    "state": {"enum": list(STATES)}, "kind": _STR, "config_hash": _STR, "run": _STR, "error": _STR, "host": _STR,
    "note": _STR, "attempts": {"type": "integer"}, "config": nullable(OBJECT),
    "outputs": nullable({"type": "array", "items": {"type": "string"}})}}


def read_record(path, schema: dict, what: str, *, tolerate_partial: bool = False) -> dict | None:
    """A JSON record of the batch folder, checked against ``schema``: None when absent (or,
    with ``tolerate_partial``, empty or cut short: a claim being written); one-line
    OutputError naming it when it is not a regular file or of the wrong shape."""
    advice = "remove it, or choose another --out"
    try:
        data = read_regular(path, limit=64 * 2**20)
    except (FileNotFoundError, NotADirectoryError):  # a folder on the way that is not one: see create()
        return None
    except OSError as e:
        raise OutputError(f"not a {what} ({e.strerror}); {advice}", path=path) from None
    if not tolerate_partial:
        return parse_json(data, schema, path=path, what=what, error=OutputError, advice=advice)
    try:
        value = json.loads(data or b"{}")
    except ValueError:
        return {}
    return check_shape(value, schema, path=path, what=what, error=OutputError, advice=advice)


def utc_now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def config_hash(config: dict) -> str:
    """A short hash of what makes an item's output what it is (inputs, method, settings)."""
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode("utf-8")).hexdigest()[:16]


class BatchState:
    """Records of the items in the batch folder ``out`` (its folders made by :meth:`create`,
    once a run has checked it may write there)."""

    def __init__(self, out):
        self.out = Path(out)
        self.root = self.out / _INTERNAL
        self.items = self.root / "items"
        self.claims = self.root / "claims"
        self.runs = self.root / "runs"
        self.manifest = self.out / "manifest.jsonl"
        self._last_manifest = 0.0
        self._dirty = True
        self._cache: dict[str, tuple[int, dict]] = {}  # key -> (mtime_ns, record) of the records read

    def create(self) -> None:
        for d in (self.root, self.items, self.claims, self.runs):
            try:
                d.mkdir(parents=True, exist_ok=True)
            except (FileExistsError, NotADirectoryError):
                bad = next(p for p in (self.root, self.items, self.claims, self.runs) if not p.is_dir())
                raise OutputError("exists and is not a folder: it holds a batch's state, so this is not a batch "
                                  "folder; choose another --out", path=bad) from None
            except OSError as e:
                raise OutputError(f"cannot create the batch state folder ({e.strerror}): choose another --out",
                                  path=d) from None

    @property
    def settings_path(self) -> Path:
        return self.root / "settings.json"

    def read_settings(self) -> dict | None:
        """The settings the folder's first run recorded (None: no run has)."""
        return read_record(self.settings_path, OBJECT, "batch settings record")

    def path(self, key: str) -> Path:
        return self.items / f"{key}.json"

    def get(self, key: str) -> dict | None:
        """The record of item ``key`` (None: none yet); OutputError when it is not one."""
        return read_record(self.path(key), RECORD, "batch item record")

    def put(self, key: str, record: dict) -> None:
        write_json(self.path(key), dict(record, item=key, time=utc_now()), overwrite=True)
        self._dirty = True

    def all(self) -> dict[str, dict]:
        """Every record in the folder (a record is read again only when its file changed)."""
        out = {}
        if not self.items.is_dir():
            return out
        for entry in os.scandir(self.items):
            if not entry.name.endswith(".json") or entry.name.startswith("."):
                continue
            key = entry.name[:-5]
            try:
                mtime = entry.stat().st_mtime_ns
                cached = self._cache.get(key)
                if cached is None or cached[0] != mtime:
                    cached = self._cache[key] = (mtime, read_record(entry.path, RECORD, "batch item record"))
            except OSError:  # another item's broken record: this run's are checked by get()
                continue
            if cached[1] is None:
                continue
            out[key] = cached[1]
        return out

    def write_manifest(self, known: dict[str, dict] | None = None, *, every: float = 0.0) -> Path | None:
        """Rewrite ``manifest.jsonl``: every item with a record in the folder, plus ``known``
        (key -> record) for items of this run that have none yet ("pending"). With ``every`` >
        0, at most once per that many seconds, and only when a record of this run changed."""
        now = time.monotonic()
        if every and (now - self._last_manifest < every or not self._dirty):
            return None
        self._last_manifest = now
        self._dirty = False
        records = dict(known or {})
        records.update(self.all())
        lines = []
        for key in sorted(records):
            r = records[key]
            line = {"item": key, "kind": r.get("kind"), "state": r.get("state", "pending"),
                    "host": r.get("host"), "time": r.get("time"), "error": r.get("error"),
                    "attempts": r.get("attempts", 0), "seconds": r.get("seconds"), "run": r.get("run"),
                    "outputs": r.get("outputs")}
            if r.get("worker_pid") is not None and line["state"] == "running":
                line["worker_pid"] = r["worker_pid"]
            lines.append(json.dumps(line, sort_keys=False, default=str))
        text = "\n".join(lines) + ("\n" if lines else "")
        from ..io import atomic_path

        with atomic_path(self.manifest) as tmp:
            tmp.write_text(text, encoding="utf-8")
        return self.manifest

    def write_run(self, run: str, record: dict) -> Path:
        return write_json(self.runs / f"{run}.json", record, overwrite=True)
