"""The state of a batch folder: an append-only ``manifest.jsonl``, and a record per item only
where one is needed (a failure).

Layout of an output folder ``DIR`` (a local or NFS folder, or an fsspec URL, see ``_store.py``)::

    DIR/<item outputs>            e.g. a__b__facetex.png + a__b__facetex.png.json
    DIR/manifest.jsonl            appended to: one JSON line per change of an item's state
    DIR/.facetex-batch/items/     <key>.json: only for failed items (error, attempts, run)
    DIR/.facetex-batch/claims/    <key>.<generation>: who computes the item now (see _claims.py)
    DIR/.facetex-batch/runs/      <run>.json: each run's command line, engine and summary
    DIR/.facetex-batch/settings.json   the settings of the folder's first run

An item is *done* when its outputs exist (the output is committed last) and its inputs are the
ones it was made from; *running* while a claim on it is held; *failed* while its record says so;
else *pending*. A done line and a failure record name the sha256 of the item's inputs
(``input_digests``, see ``_digests.py``), and so does the sidecar (its ``batch`` field): a rerun
recomputes an item whose inputs have other digests now. Lines and records written before
batches kept digests have none, and their items stay done (or failed) as before. ``manifest.jsonl`` is
the log of those changes for people and ``facetex batch status``: each line is one item's
state at one time (the last line of an item wins), written by appending, never by rewriting
(10 000 items append 10 000s of short lines, not a file per completion). Paths in it are
relative to ``DIR``, so a moved folder still reads (and resumes) as it was. A run appends its
lines with one ``write`` per flush; several runs on one host append whole lines. Over NFS from
several hosts at once, or on object storage (which has no append: the object is rewritten),
a line of one run can be lost when another appends at the same moment; the outputs, claims
and failure records, not the manifest, decide what a run computes.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path

from .._schema import OBJECT, check_shape, nullable, parse_json
from ..errors import OutputError
from ._store import Store, join, store_for

__all__ = ["BatchState", "config_hash", "utc_now", "read_record", "read_manifest", "STATES", "MANIFEST_LINE"]

STATES = ("pending", "running", "done", "failed")
_INTERNAL = ".facetex-batch"
_STR = nullable({"type": "string"})
_DIGESTS = nullable({"type": "object", "additionalProperties": {"type": "string"}})  # input -> sha256
RECORD = {"type": "object", "properties": {
    "state": {"enum": list(STATES)}, "kind": _STR, "config_hash": _STR, "run": _STR, "error": _STR, "host": _STR,
    "note": _STR, "attempts": {"type": "integer"}, "config": nullable(OBJECT),
    "outputs": nullable({"type": "array", "items": {"type": "string"}}), "input_digests": _DIGESTS}}
_NUM = nullable({"type": "number"})
MANIFEST_LINE = {"type": "object", "required": ["item", "state"], "properties": {
    "item": {"type": "string"}, "state": {"enum": list(STATES)}, "kind": _STR, "time": _STR, "host": _STR,
    "run": _STR, "error": _STR, "attempts": nullable({"type": "integer"}), "seconds": _NUM, "peak_rss_mb": _NUM,
    "config_hash": _STR, "config": nullable(OBJECT), "outputs": nullable({"type": "array", "items": {"type": "string"}}),
    "worker_pid": nullable({"type": "integer"}), "threads": nullable({"type": "integer"}), "note": _STR,
    "input_digests": _DIGESTS}}


def read_record(path, schema: dict, what: str, *, tolerate_partial: bool = False, store: Store | None = None
                ) -> dict | None:
    """A JSON record of the batch folder, checked against ``schema``: None when absent (or,
    with ``tolerate_partial``, empty or cut short: a claim being written); one-line
    OutputError naming it when it is not a regular file or of the wrong shape."""
    advice = "remove it, or choose another --out"
    store = store or store_for(path)
    try:
        data = store.read(path, limit=64 * 2**20)
    except (FileNotFoundError, NotADirectoryError):  # a folder on the way that is not one: see create()
        return None
    except OSError as e:
        raise OutputError(f"not a {what} ({e.strerror or e}); {advice}", path=path) from None
    if not tolerate_partial:
        return parse_json(data, schema, path=path, what=what, error=OutputError, advice=advice)
    try:
        value = json.loads(data or b"{}")
    except ValueError:
        return {}
    return check_shape(value, schema, path=path, what=what, error=OutputError, advice=advice)


def read_manifest(path, store: Store | None = None) -> dict[str, dict]:
    """The last line of every item in the manifest at ``path`` ({} when there is none). Lines
    that are not JSON objects of the manifest's shape (a line cut short by a crash, two
    appends of other hosts run together) are skipped."""
    store = store or store_for(path)
    try:
        data = store.read(path)
    except (FileNotFoundError, NotADirectoryError):
        return {}
    except OSError as e:
        raise OutputError(f"cannot read the batch manifest ({e.strerror or e})", path=path) from None
    last: dict[str, dict] = {}
    from .._schema import _validator

    v = _validator(MANIFEST_LINE)
    for raw in data.splitlines():
        try:
            line = json.loads(raw)
        except ValueError:
            continue
        if isinstance(line, dict) and v.is_valid(line):
            last[line["item"]] = line
    return last


def utc_now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def config_hash(config: dict) -> str:
    """A short hash of what makes an item's output what it is (inputs, method, settings)."""
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode("utf-8")).hexdigest()[:16]


class BatchState:
    """The state of the batch folder ``out`` (its folders made by :meth:`create`, once a run has
    checked it may write there). Manifest lines are buffered by :meth:`log` and appended by
    :meth:`flush`."""

    def __init__(self, out, store: Store | None = None):
        self.out = str(out)
        self.store = store or store_for(out)
        as_path = (lambda p: p) if self.store.remote else Path  # local folders as Paths, URLs as strings
        self.root = as_path(join(self.out, _INTERNAL))
        self.items = as_path(join(self.root, "items"))
        self.claims = as_path(join(self.root, "claims"))
        self.runs = as_path(join(self.root, "runs"))
        self.manifest = as_path(join(self.out, "manifest.jsonl"))
        self._buffer: list[str] = []
        self._last_flush = 0.0

    def create(self) -> None:
        for d in (self.root, self.items, self.claims, self.runs):
            if self.store.remote:
                continue  # object storage has no folders
            try:
                self.store.makedirs(d)
            except (FileExistsError, NotADirectoryError):
                bad = next(p for p in (self.root, self.items, self.claims, self.runs) if not self.store.isdir(p))
                raise OutputError("exists and is not a folder: it holds a batch's state, so this is not a batch "
                                  "folder; choose another --out", path=bad) from None
            except OSError as e:
                raise OutputError(f"cannot create the batch state folder ({e.strerror}): choose another --out",
                                  path=d) from None

    @property
    def settings_path(self):
        return join(self.root, "settings.json") if self.store.remote else Path(self.root, "settings.json")

    def read_settings(self) -> dict | None:
        """The settings the folder's first run recorded (None: no run has)."""
        return read_record(self.settings_path, OBJECT, "batch settings record", store=self.store)

    def record_settings(self, settings: dict) -> bool:
        """Record ``settings`` unless a record exists (exclusive create); whether this call did."""
        try:
            self.store.create(self.settings_path, json.dumps(settings, indent=2, sort_keys=True).encode() + b"\n")
        except FileExistsError:
            return False
        return True

    def path(self, key: str):
        return join(self.items, f"{key}.json") if self.store.remote else Path(self.items, f"{key}.json")

    def get(self, key: str) -> dict | None:
        """The record of item ``key`` (None: none); OutputError when it is not one."""
        return read_record(self.path(key), RECORD, "batch item record", store=self.store)

    def put(self, key: str, record: dict) -> None:
        from ..io import encode_json

        self.store.put(self.path(key), encode_json(dict(record, item=key, time=utc_now())))

    def remove(self, key: str) -> None:
        """Remove item ``key``'s record (it is done: its outputs say so)."""
        self.store.remove(self.path(key))

    def recorded(self) -> set[str]:
        """Keys of the items with a record (one listing)."""
        return {n[:-5] for n in self.store.names(self.items) if n.endswith(".json") and not n.startswith(".")}

    def relative(self, path: str) -> str:
        """``path`` relative to the folder (as the manifest names outputs)."""
        if self.store.remote:
            base = self.out.rstrip("/") + "/"
            return path[len(base):] if str(path).startswith(base) else str(path)
        base, real = os.path.realpath(self.out), os.path.realpath(path)
        return os.path.relpath(real, base) if real.startswith(base + os.sep) else str(path)

    def log(self, key: str, record: dict) -> None:
        """Buffer a manifest line: item ``key``'s state now (see :meth:`flush`)."""
        line = {"item": key, "state": record.get("state", "pending"), "time": utc_now(), "kind": record.get("kind"),
                "host": record.get("host"), "run": record.get("run"), "attempts": record.get("attempts", 0),
                "error": record.get("error")}
        for k in ("seconds", "peak_rss_mb", "threads", "worker_pid", "note", "config_hash", "config", "input_digests"):
            if record.get(k) is not None:
                line[k] = record[k]
        if record.get("outputs"):
            line["outputs"] = [self.relative(p) for p in record["outputs"]]
        self._buffer.append(json.dumps(line, default=str))

    def flush(self, every: float = 0.0) -> None:
        """Append the buffered lines (one write); with ``every`` > 0 at most once per that many seconds."""
        now = time.monotonic()
        if not self._buffer or (every and now - self._last_flush < every):
            return
        data = ("\n".join(self._buffer) + "\n").encode("utf-8")
        try:
            self.store.append(self.manifest, data)
        except OSError as e:
            raise OutputError(f"cannot append to the batch manifest ({e.strerror or e})", path=self.manifest) \
                from None
        self._buffer.clear()
        self._last_flush = now

    def read_manifest(self) -> dict[str, dict]:
        return read_manifest(self.manifest, self.store)

    def write_run(self, run: str, record: dict) -> str:
        from ..io import encode_json

        path = join(self.runs, f"{run}.json")
        self.store.put(path, encode_json(record))
        return path
