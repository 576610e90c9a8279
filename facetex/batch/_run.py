"""Running a batch: claim, schedule, retry, record; and ``map_items`` for the benches.

:func:`run_batch` runs every item of a list on an engine, with the output folder as the only
shared state: finished items (outputs present, record "done", inputs with the sha256 the record
names) are skipped, failed items are skipped unless ``retry_failed`` or an input changed since,
items claimed by another live run are left to it (and waited for), and a worker that dies
fails only its item, which is run again up to ``max_retries`` times. An interrupt (Ctrl-C,
SIGTERM) cancels the running items (their temporary files are removed), puts them back to
"pending", releases the claims and re-raises.
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

from ..errors import BadInputError, OutputError
from ..io import check_output_path
from ._claims import Claims
from ._digests import InputDigests, digests_differ
from ._state import BatchState, config_hash, utc_now
from ._store import STAGED_FN, Store, is_url, name_of, parent_of, run_staged_item, store_for
from .engines import Engine, Outcome, Resources

__all__ = ["Item", "BatchSummary", "run_batch", "map_items", "remove_item_temporaries", "run_tag"]

_HOST = socket.gethostname()


@dataclass
class Item:
    """One unit of work: ``fn(payload)`` writes ``outputs`` (absolute paths, the first one's
    stem is ``key``, the last one the sidecar) atomically. ``config`` is what makes the outputs
    what they are: a finished item made with another config is an error, not a skip.
    ``inputs``: the files (or folders) it reads (no item of the run may write one of them); a
    rerun computes the item again when their bytes changed (see :func:`run_batch`)."""

    key: str
    kind: str
    fn: Callable[[dict], Any]
    payload: dict
    outputs: tuple[str, ...]
    config: dict
    resources: Resources = Resources()
    inputs: tuple[str, ...] = ()


@dataclass
class BatchSummary:
    run: str
    out: str
    manifest: str
    engine: dict
    total: int = 0
    skipped_done: int = 0  # finished before this run
    skipped_failed: int = 0  # failed before, not retried
    done: int = 0  # computed by this run
    done_elsewhere: int = 0  # computed by another run meanwhile
    failed: int = 0
    failed_elsewhere: int = 0  # failed in another run meanwhile (not retried here)
    inputs_changed: int = 0  # done or failed before, run again because an input has other bytes now
    retried: int = 0  # worker deaths that were retried
    remaining: int = 0
    seconds: float = 0.0
    computed: list = field(default_factory=list)  # keys computed by this run
    failures: list = field(default_factory=list)  # (key, error)
    failures_elsewhere: list = field(default_factory=list)  # (key, run, error): another run's failures
    # per computed item: key, seconds, cpu_s, started (epoch), overhead_s, host, pid, rss, worker_spawned (local)
    item_stats: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.failed == 0 and self.failed_elsewhere == 0 and self.skipped_failed == 0 and self.remaining == 0

    def as_dict(self) -> dict:
        d = {k: getattr(self, k) for k in ("run", "out", "manifest", "engine", "total", "skipped_done",
                                           "skipped_failed", "done", "done_elsewhere", "failed", "failed_elsewhere",
                                           "inputs_changed", "retried", "remaining", "seconds", "computed")}
        d["failures"] = [{"item": k, "error": e} for k, e in self.failures]
        d["failures_elsewhere"] = [{"item": k, "run": r, "error": e} for k, r, e in self.failures_elsewhere]
        d["rate_per_min"] = 60.0 * self.done / self.seconds if self.seconds > 0 else None
        return d


def run_tag(run: str) -> str:
    """The tag a run's workers put into their temporary files' names (letters and digits)."""
    return hashlib.sha256(run.encode("utf-8")).hexdigest()[:12]


def remove_item_temporaries(folder, key: str, tags: Iterable[str]) -> list[Path]:
    """Remove the temporary files that an interrupted or killed item of the runs tagged ``tags``
    left in ``folder``: a batch worker's atomic writers name them ``.<output name>.<tag>.<random>
    <ext>`` (a writer nested in another ``..<output name>.<tag>...``), and item keys contain no
    dots. Anything else (a user's ``.<output name>.notes``) is not ours and stays. Object
    storage has none (a worker uploads whole objects)."""
    removed: list[Path] = []
    if is_url(folder):
        return removed
    prefix = f"{key}."
    marks = [f".{t}." for t in tags if t]
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for e in entries:
        if e.name.startswith(".") and e.name.lstrip(".").startswith(prefix) and any(m in e.name for m in marks) \
                and e.is_file(follow_symlinks=False):
            try:
                os.unlink(e.path)
                removed.append(Path(e.path))
            except OSError:
                pass
    return removed


class _Outputs:
    """Which outputs exist: one listing of the output folder at the start (10 000 items on
    object storage: a few list requests, not 20 000), single checks afterwards."""

    def __init__(self, store: Store, out: str):
        self.store = store
        self.out = self._key(out)
        self.listed = store.names(out)

    def _key(self, folder) -> str:
        return str(folder).rstrip("/") if self.store.remote else os.path.realpath(folder)

    def initial(self, it: Item) -> list[bool]:
        return [name_of(p) in self.listed if self._key(parent_of(p)) == self.out else self.store.exists(p)
                for p in it.outputs]

    def now(self, it: Item) -> list[bool]:
        return [self.store.exists(p) for p in it.outputs]


def _made_by_batch(sidecar: str, key: str, store: Store | None = None) -> bool:
    """Whether ``sidecar`` is a batch item ``key``'s sidecar (a regular file whose provenance
    names the item): the only half of an item a run may remove. Batch workers commit the
    sidecar first, so a commit cut short leaves exactly that."""
    try:
        record = json.loads((store or store_for(sidecar)).read(sidecar, limit=16 * 2**20))
    except (OSError, ValueError):
        return False
    batch = record.get("batch") if isinstance(record, dict) else None
    return isinstance(batch, dict) and batch.get("item") == key


def _sidecar_batch(sidecar: str, key: str, store: Store) -> dict | None:
    """The ``batch`` field of ``sidecar`` when it is batch item ``key``'s sidecar (else None)."""
    try:
        record = json.loads(store.read(sidecar, limit=16 * 2**20))
    except (OSError, ValueError):
        return None
    batch = record.get("batch") if isinstance(record, dict) else None
    return batch if isinstance(batch, dict) and batch.get("item") == key else None


def _check_not_users(it: Item, exists: list[bool], store: Store) -> None:
    """Refuse (before any work) an unfinished item whose output names hold files the batch did
    not make: an output without its sidecar, a sidecar that is not this item's."""
    if all(exists) or not any(exists):
        return
    *outputs, sidecar = it.outputs
    for p, e in zip(outputs, exists):
        if e:
            raise OutputError(f"exists without its sidecar {name_of(sidecar)}, so this batch did not make it and "
                              "will not replace it: move it away, or choose another --out", path=p)
    if not _made_by_batch(sidecar, it.key, store):
        raise OutputError(f"exists without {name_of(outputs[0])} and is not that batch item's sidecar: "
                          "move it away, or choose another --out", path=sidecar)


def _check_inputs_not_outputs(items: Sequence[Item]) -> None:
    """No item may write a file another item reads (``--out .`` beside the inputs)."""
    def real(p):
        return str(p).rstrip("/") if is_url(p) else os.path.realpath(p)

    writers = {real(p): it for it in items for p in it.outputs}
    for it in items:
        for p in it.inputs:
            other = writers.get(real(p))
            if other is not None:
                where = f" ({it.payload['source']})" if it.payload.get("source") else ""
                raise BadInputError(f"is an input{where} and also the output of item {other.key}: choose another "
                                    "--out", path=p)


def _describe_settings_change(old: dict | None, new: dict) -> str:
    if not isinstance(old, dict):
        return "other settings"
    diff = [f"{k}: {old.get(k)!r} -> {new.get(k)!r}" for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k)]
    return "; ".join(diff[:3]) or "other settings"


def _check_folder_settings(state: BatchState, new: dict) -> bool:
    """Refuse a run whose settings differ from those the folder's first run recorded (two runs
    with other --size on one folder would mix outputs of both, under the same names). Returns
    whether the folder has recorded settings."""
    old = state.read_settings()
    if old is None:
        return False
    diff = [f"{k} {old.get(k)!r} (this run: {new.get(k)!r})" for k in sorted(set(old) | set(new))
            if old.get(k) != new.get(k)]
    if diff:
        raise OutputError(f"holds a batch made with other settings: {'; '.join(diff)}: choose another --out, or "
                          "run with the folder's settings", path=state.out)
    return True


def _record_folder_settings(state: BatchState, new: dict) -> None:
    """Record ``new`` as the folder's settings; of two runs starting at once one records (an
    exclusive create), the other is checked against it."""
    try:
        if state.record_settings(new):
            return
    except OSError as e:
        raise OutputError(f"cannot record the batch settings ({e.strerror or e})", path=state.settings_path) \
            from None
    _check_folder_settings(state, new)


def _staged(it: Item, payload: dict) -> tuple[Callable, dict]:
    """The function and payload of an item whose output is a URL: :func:`run_staged_item`
    fetches its remote inputs, runs ``it.fn`` on local files and uploads the outputs."""
    remote = [k for k, v in payload.items() if isinstance(v, str) and v in it.inputs and is_url(v)]
    return run_staged_item, dict(payload, **{STAGED_FN: it.fn, "_remote_inputs": remote})


def run_batch(items: Sequence[Item], out, engine: Engine, *, retry_failed: bool = False, max_retries: int = 2,
              claim_timeout: float = 300.0, progress: Callable[..., None] | None = None, poll: float = 1.0,
              record: dict | None = None, wait_for_others: bool = True, settings: dict | None = None) -> BatchSummary:
    """Run ``items`` on ``engine`` (started by the caller), with ``out`` (a folder or an fsspec
    URL) as the shared state (see the module docstring and :mod:`facetex.batch._state`).
    ``progress(**counts)`` is called after every change with the counts done, failed,
    remaining, running, waiting (items another run is computing) and done_elsewhere.
    ``record``: extra fields for the run's record (command line, settings). ``settings``: what
    every item shares and no output name shows (``--size`` ...); the folder keeps the first
    run's, and a run with others is refused. Returns the summary; raises OutputError before
    any work when the folder's settings differ or a finished item was made with other
    settings, and re-raises KeyboardInterrupt after cleaning up.

    An item is done when its outputs exist and the sha256 of its input files (a folder input:
    of its files) are those its done record names; one whose inputs were replaced under the
    same names is computed again and its outputs (made by a batch: its sidecar says so) are
    replaced, the output then the sidecar, each by a rename. Each input is hashed once per
    run. Items recorded before batches kept digests name none: they stay done, as before (no
    recompute after an upgrade), and their current digests are recorded for the next run."""
    out = str(out).rstrip("/") if is_url(out) else str(Path(out))
    items = list(items)
    seen: dict[str, Item] = {}
    for it in items:
        if it.key in seen:
            raise BadInputError(f"two items would write the same output {it.outputs[0]} "
                                f"({seen[it.key].payload.get('source')} and {it.payload.get('source')})")
        if "." in it.key:
            raise BadInputError(f"item key {it.key!r} contains a dot")
        seen[it.key] = it
    _check_inputs_not_outputs(items)
    store = store_for(out)
    state = BatchState(out, store)
    claims = Claims(state.claims, timeout=claim_timeout, store=store)
    tag = run_tag(claims.run)
    summary = BatchSummary(run=claims.run, out=out, manifest=str(state.manifest), engine=engine.describe(),
                           total=len(items))
    hashes = {it.key: config_hash(it.config) for it in items}
    hasher = InputDigests()
    digests: dict[str, dict] = {}  # key -> {input: sha256}, hashed when first needed

    def digests_of(it: Item) -> dict:
        d = digests.get(it.key)
        if d is None:
            d = digests[it.key] = hasher.of(it.inputs)
        return d

    def changed(record: dict | None, it: Item) -> bool:
        """Whether ``record`` names input digests and ``it``'s inputs have others now."""
        return isinstance(record, dict) and isinstance(record.get("input_digests"), dict) and \
            digests_differ(record, digests_of(it))

    t_start = time.perf_counter()

    # -- what is left to do (checked before any work): one listing each of the outputs, the
    # records, the claims, and one read of the manifest
    outputs = _Outputs(store, out)
    last = state.read_manifest()
    recorded = state.recorded()
    claimed = claims.claimed()
    todo: deque[Item] = deque()
    new: list[Item] = []  # items the manifest has never listed: "pending" lines
    found: list[Item] = []  # finished, the manifest lists no done line with digests: recorded after the checks
    stale: set[str] = set()  # finished items whose inputs changed since: computed again, outputs replaced
    not_ours = []
    clashes = []
    for it in items:
        rec = state.get(it.key) if it.key in recorded else None
        line = last.get(it.key)
        exists = outputs.initial(it)
        done_by = rec if rec is not None and rec.get("state") == "done" else \
            line if line is not None and line.get("state") == "done" else None
        if done_by is not None and done_by.get("config_hash") not in (None, hashes[it.key]) and all(exists):
            clashes.append((it, done_by))
            continue
        # also: a claim file of the wrong shape is refused before any work
        holder = claims.holder(it.key) if it.key in claimed else None
        if all(exists) and (done_by is not None or holder is None or holder["expired"]):
            # found without a done line: its sidecar says what it was made from
            made_by = done_by if done_by is not None else _sidecar_batch(it.outputs[-1], it.key, store)
            if changed(made_by, it):
                sidecar = made_by if done_by is None else _sidecar_batch(it.outputs[-1], it.key, store)
                if sidecar is None:
                    not_ours.append(it)
                    continue
                if sidecar.get("input_digests") != digests_of(it):
                    stale.add(it.key)
                    summary.inputs_changed += 1
                    todo.append(it)
                    continue
                # else made again from these inputs by a run that lost its done line (its sidecar is
                # committed last): done, and the line is written now
            summary.skipped_done += 1
            # no done line with these digests (none: made before batches kept them): one is written
            if line is None or line.get("state") != "done" or line.get("input_digests") != digests_of(it):
                found.append(it)
            continue
        if rec is not None and rec.get("state") == "failed" and changed(rec, it):
            summary.inputs_changed += 1  # failed on other bytes: tried again
        elif rec is not None and rec.get("state") == "failed" and not retry_failed and \
                rec.get("config_hash") in (None, hashes[it.key]):  # failed with other settings: try the new ones
            summary.skipped_failed += 1
            summary.failures.append((it.key, rec.get("error")))
            continue
        _check_not_users(it, exists, store)
        todo.append(it)
        if line is None:
            new.append(it)
    if settings is not None:
        settings = json.loads(json.dumps(settings, sort_keys=True, default=str))  # as it is stored
        recorded_settings = _check_folder_settings(state, settings)
    if not_ours:
        raise OutputError(f"its item's input changed since it was made, but it is not that batch item's sidecar, so "
                          f"this batch will not replace {name_of(not_ours[0].outputs[0])} ({len(not_ours)} such "
                          "item(s)): move them away, or choose another --out", path=not_ours[0].outputs[-1])
    if clashes:
        it, rec = clashes[0]
        raise OutputError(f"holds {len(clashes)} item(s) made with other settings (e.g. {it.key}: "
                          f"{_describe_settings_change(rec.get('config'), it.config)}): choose another --out, or "
                          "remove those outputs", path=out)
    if not store.remote:
        check_output_path(state.manifest, overwrite=True)  # a folder or FIFO of that name: refused before any work
    state.create()
    if store.remote:
        store.check_exclusive(state.root)
    if settings is not None and not recorded_settings:
        _record_folder_settings(state, settings)
    for it in found:
        line = last.get(it.key)
        note = "input digests recorded" if line is not None and line.get("state") == "done" else "outputs found"
        state.log(it.key, {"kind": it.kind, "state": "done", "config_hash": hashes[it.key], "config": it.config,
                           "outputs": list(it.outputs), "run": claims.run, "note": note,
                           "input_digests": digests[it.key]})
        if it.key in recorded:  # a failure of before, done since (by a run that lost its manifest line)
            state.remove(it.key)
            recorded.discard(it.key)
    for it in new:
        state.log(it.key, {"kind": it.kind, "state": "pending", "run": claims.run})

    running: dict[int, dict] = {}  # handle -> {item, attempt, submitted}
    elsewhere: dict[str, Item] = {}  # claimed by another run
    attempts: dict[str, int] = {}
    heartbeat_every = max(1.0, min(30.0, claim_timeout / 5.0))
    flush_every = 10.0 if store.remote else 0.0  # object storage rewrites the object on append
    last_beat = last_look = time.monotonic()

    def report():
        summary.remaining = len(todo) + len(running) + len(elsewhere)
        if progress:
            progress(done=summary.done, failed=summary.failed, remaining=summary.remaining,
                     running=len(running), waiting=len(elsewhere), done_elsewhere=summary.done_elsewhere)

    def base(it: Item) -> dict:
        return {"kind": it.kind, "config_hash": hashes[it.key], "run": claims.run, "outputs": list(it.outputs),
                "attempts": attempts.get(it.key, 0)}

    def finished(it: Item) -> bool:
        """Whether ``it`` is done now (by another run): its outputs exist and, when they were
        made from other inputs, the sidecar now names the current ones (it is committed last)."""
        if not all(outputs.now(it)):
            return False
        if it.key not in stale:
            return True
        made_by = _sidecar_batch(it.outputs[-1], it.key, store)
        return made_by is not None and made_by.get("input_digests") == digests.get(it.key)

    def fail(it: Item, error: str, error_type: str | None = None, host: str = _HOST, pid=None) -> None:
        failure = dict(base(it), state="failed", host=host, error=error, error_type=error_type, worker_pid=pid,
                       config=it.config, input_digests=digests.get(it.key))
        state.put(it.key, failure)
        recorded.add(it.key)
        state.log(it.key, failure)
        claims.release(it.key)
        summary.failed += 1
        summary.failures.append((it.key, error))

    def start(it: Item) -> None:
        attempts[it.key] = attempts.get(it.key, 0) + 1
        folder = parent_of(it.outputs[0])
        rec = state.get(it.key) if it.key in recorded else None
        before = {str((rec or {}).get("run")), str((last.get(it.key) or {}).get("run"))}
        remove_item_temporaries(folder, it.key, {tag, *(run_tag(r) for r in before if r != "None")})
        sidecar = it.outputs[-1]
        if not any(store.exists(p) for p in it.outputs[:-1]) and _made_by_batch(sidecar, it.key, store):
            try:  # a commit cut short (killed between its renames): never half an item
                store.remove(sidecar)
            except OSError:
                pass
        # the sidecar records the input digests (the worker's provenance keeps "batch"); "replace":
        # the outputs of other inputs are there, and the worker replaces them (output first, sidecar last)
        payload = dict(it.payload, batch={"run": claims.run, "item": it.key, "attempt": attempts[it.key],
                                          "engine": engine.name, "tag": tag, "input_digests": digests[it.key],
                                          **({"replace": True} if it.key in stale else {})})
        fn = it.fn
        if store.remote:
            fn, payload = _staged(it, payload)
        h = engine.submit(fn, payload, it.resources)
        running[h] = {"item": it, "submitted": time.time()}
        state.log(it.key, dict(base(it), state="running", host=_HOST, worker_pid=engine.worker_pid(h)))

    def fill() -> None:
        while todo and len(running) < engine.slots:
            it = todo.popleft()
            if claims.acquire(it.key) is None:
                elsewhere[it.key] = it
                continue
            # re-checked under the claim: another run may have finished it
            if finished(it):
                claims.release(it.key)
                summary.done_elsewhere += 1
                continue
            try:  # hashed before the worker reads them: an input replaced meanwhile makes the next run redo it
                digests_of(it)
            except BadInputError as e:
                fail(it, str(e), type(e).__name__)
                continue
            rec = state.get(it.key)
            if rec is not None and rec.get("config_hash") == hashes[it.key] and rec.get("state") == "failed" \
                    and rec.get("run") != claims.run and not retry_failed and it.key not in attempts \
                    and not changed(rec, it):
                claims.release(it.key)
                summary.failed_elsewhere += 1
                summary.failures_elsewhere.append((it.key, rec.get("run"), rec.get("error")))
                continue
            if rec is not None:
                recorded.add(it.key)
            start(it)

    def finish(o: Outcome) -> None:
        entry = running.pop(o.handle)
        it: Item = entry["item"]
        stats = o.stats or {}
        host = stats.get("host", _HOST)
        if o.ok:
            value = o.value if isinstance(o.value, dict) else {}
            if it.key in recorded:  # a failure of before: the outputs say "done" now
                state.remove(it.key)
                recorded.discard(it.key)
            state.log(it.key, dict(base(it), state="done", host=host, worker_pid=stats.get("pid"),
                                   seconds=stats.get("seconds"), peak_rss_mb=stats.get("peak_rss_mb"),
                                   threads=stats.get("threads"), config=it.config, note=value.get("note"),
                                   input_digests=digests[it.key]))
            claims.release(it.key)
            if value.get("note") == "written by another run":
                summary.done_elsewhere += 1
            else:
                summary.done += 1
                summary.computed.append(it.key)
                wall = (stats.get("returned") or time.time()) - entry["submitted"]
                summary.item_stats.append({"item": it.key, "seconds": stats.get("seconds"), "wall_s": wall,
                                           "overhead_s": wall - (stats.get("seconds") or 0.0), "host": host,
                                           "pid": stats.get("pid"), "peak_rss_mb": stats.get("peak_rss_mb"),
                                           "cpu_s": stats.get("cpu_s"), "started": stats.get("started"),
                                           "worker_spawned": stats.get("worker_spawned")})
            return
        remove_item_temporaries(parent_of(it.outputs[0]), it.key, [tag])
        if o.died and attempts.get(it.key, 0) <= max_retries:
            summary.retried += 1
            state.log(it.key, dict(base(it), state="pending", host=host, error=f"retrying: {o.error}"))
            start(it)  # the claim is still ours
            return
        error = o.error or "failed"
        if o.died:
            error = f"{error} (attempt {attempts.get(it.key, 1)} of {max_retries + 1})"
        fail(it, error, o.error_type, host, stats.get("pid"))

    def look_elsewhere() -> None:
        for key in list(elsewhere):
            it = elsewhere[key]
            info = claims.holder(key)
            if info is not None and not info["expired"]:
                continue
            del elsewhere[key]
            if info is not None:  # its run died: ours now
                todo.appendleft(it)
            elif finished(it):
                summary.done_elsewhere += 1
            else:
                rec = state.get(key)
                if rec is not None and rec.get("state") == "failed" and \
                        not (retry_failed and rec.get("run") == claims.run):
                    summary.failed_elsewhere += 1
                    summary.failures_elsewhere.append((key, rec.get("run"), rec.get("error")))
                else:
                    todo.append(it)

    try:
        report()
        state.flush()
        while todo or running or elsewhere:
            fill()
            report()
            if running:
                for o in engine.wait(timeout=poll):
                    finish(o)
                    report()
            elif elsewhere and not todo:
                if not wait_for_others:
                    break
                time.sleep(poll)
            now = time.monotonic()
            if now - last_beat >= heartbeat_every:
                claims.heartbeat()
                last_beat = now
            if elsewhere and now - last_look >= max(poll, 2.0):
                look_elsewhere()
                last_look = now
            state.flush(every=flush_every)
    except BaseException:
        engine.cancel()
        for entry in running.values():
            it = entry["item"]
            remove_item_temporaries(parent_of(it.outputs[0]), it.key, [tag])
            state.log(it.key, dict(base(it), state="pending", host=_HOST, error="interrupted"))
        summary.remaining = len(todo) + len(running) + len(elsewhere)
        claims.release_all()
        try:
            state.flush()
        except (OSError, OutputError):
            pass
        raise
    finally:
        summary.seconds = time.perf_counter() - t_start
    summary.remaining = len(todo) + len(elsewhere)
    state.flush()
    state.write_run(claims.run, {**(record or {}), "run": claims.run, "host": _HOST, "pid": os.getpid(),
                                 "finished_utc": utc_now(), "summary": summary.as_dict(),
                                 "items": summary.item_stats})
    report()
    return summary


def map_items(engine: Engine, fn: Callable, payloads: Iterable, *, resources: Resources = Resources(),
              max_retries: int = 2, progress: Callable[..., None] | None = None) -> list:
    """``[fn(p) for p in payloads]`` on ``engine`` (results in order), for the benches: no
    claims and no manifest (their own result stores resume them). A worker that dies is
    retried up to ``max_retries`` times; an item's error is raised as it was (its one line) after
    the running items are cancelled. ``progress(n=1, index=i, result=r)`` per finished item."""
    from ..errors import FacetexError

    payloads = list(payloads)
    results: list = [None] * len(payloads)
    todo = deque(range(len(payloads)))
    running: dict[int, int] = {}
    tries = [0] * len(payloads)
    try:
        while todo or running:
            while todo and len(running) < max(1, engine.slots):
                i = todo.popleft()
                tries[i] += 1
                running[engine.submit(fn, payloads[i], resources)] = i
            for o in engine.wait(timeout=1.0):
                i = running.pop(o.handle)
                if o.ok:
                    results[i] = o.value
                    if progress:
                        progress(n=1, index=i, result=o.value)
                elif o.died and tries[i] <= max_retries:
                    todo.appendleft(i)
                else:
                    raise FacetexError(o.error or "an item failed")
    except BaseException:
        engine.cancel()
        raise
    return results
