"""``facetex batch status DIR``: what a batch folder (local or a URL) holds, from its manifest,
claims and run records: counts per state, throughput, failures grouped by error, slowest items;
on request, the done items whose inputs changed since (a rerun computes them again)."""

from __future__ import annotations

import json
import re
from collections import Counter
from datetime import datetime, timezone

from ..errors import BadInputError
from ._claims import Claims
from ._digests import InputDigests, digests_differ
from ._state import BatchState, read_record
from ._store import is_url, join, store_for

__all__ = ["batch_status", "error_group"]

_PATHISH = re.compile(r"(?:[A-Za-z][A-Za-z0-9+.\-]*://|/|\.{0,2}/)?[^\s:'\"()]*/[^\s:'\"()]+|"
                      r"[^\s:'\"()/]+\.(?:jpe?g|png|tiff?|webp|bmp|mp4|mov|persona|json)\b", re.I)


def error_group(error: str | None) -> str:
    """The error with its file names and numbers masked: the errors of one cause, on other
    files, fall into one group."""
    text = _PATHISH.sub("<file>", str(error or "failed"))
    return re.sub(r"\b\d+(\.\d+)?\b", "<n>", text)


def _time(s) -> float | None:
    try:
        return datetime.strptime(str(s), "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=timezone.utc).timestamp()
    except (TypeError, ValueError):
        return None


def _stale(last: dict[str, dict], examples: int) -> dict:
    """The done items whose recorded input digests differ from their inputs' now (an input
    that cannot be read counts as changed); items recorded without digests are not checked."""
    hasher = InputDigests()
    checked, items = 0, []
    for key, line in sorted(last.items()):
        recorded = line.get("input_digests")
        if line["state"] != "done" or not isinstance(recorded, dict):
            continue
        checked += 1
        try:
            now = hasher.of(recorded)
        except BadInputError:
            now = None
        if now is None or digests_differ(line, now):
            items.append(key)
    return {"checked": checked, "count": len(items), "items": items[:examples]}


def batch_status(folder, *, slowest: int = 10, examples: int = 5, check_inputs: bool = False) -> dict:
    """The status of the batch folder ``folder`` (a path or an fsspec URL).

    Parameters
    ----------
    folder : str or os.PathLike
        The ``--out`` of ``facetex batch``.
    slowest : int, optional
        How many of the slowest finished items to list.
    examples : int, optional
        How many items to name per group of failures (and of changed inputs).
    check_inputs : bool, optional
        Also hash the inputs of the done items (each file once) and count those whose inputs
        changed since they were made, which a rerun computes again.

    Returns
    -------
    dict
        ``folder, total, counts`` (per state: pending, running, done, failed), ``throughput``
        (``items_per_hour`` over the span from the first line to the last finished item, and
        per run from its record), ``failures`` (groups of one cause: ``error``, ``count``,
        ``items``), ``slowest`` (``item, seconds, host``), ``runs`` and ``inputs_changed``
        (with ``check_inputs``: ``checked``, the done items recorded with input digests;
        ``count``; ``items``, the first ones; else None).

    Raises
    ------
    BadInputError
        When ``folder`` is not a batch folder (no ``manifest.jsonl``).
    """
    out = str(folder).rstrip("/") if is_url(folder) else str(folder)
    store = store_for(out)
    state = BatchState(out, store)
    if not store.exists(state.manifest):
        raise BadInputError("not a batch folder (no manifest.jsonl): give the --out of `facetex batch`", path=out)
    last = state.read_manifest()
    claims = Claims(state.claims, store=store)
    claimed = claims.claimed()
    counts = Counter()
    for key, line in last.items():
        st = line["state"]
        if st == "running" and key not in claimed:  # its run ended without a word (killed): pending
            st = "pending"
        counts[st] += 1
    groups: dict[str, dict] = {}
    for key, line in sorted(last.items()):
        if line["state"] != "failed":
            continue
        g = groups.setdefault(error_group(str(line.get("error")).replace(key, "<item>")), {"error": line.get("error"), "count": 0, "items": []})
        g["count"] += 1
        if len(g["items"]) < examples:
            g["items"].append(key)
    failures = sorted(groups.values(), key=lambda g: (-g["count"], g["error"] or ""))
    done = [line for line in last.values() if line["state"] == "done" and isinstance(line.get("seconds"), (int, float))]
    slow = sorted(done, key=lambda line: -line["seconds"])[:max(0, int(slowest))]
    times = [t for t in (_time(line.get("time")) for line in last.values()) if t is not None]
    done_times = [t for t in (_time(line.get("time")) for line in last.values() if line["state"] == "done")
                  if t is not None]
    first = None
    try:  # the first line of the manifest: when the work began
        head = store.read(state.manifest).split(b"\n", 1)[0]
        first = _time(json.loads(head).get("time"))
    except (OSError, ValueError, AttributeError):
        first = min(times) if times else None
    span = (max(done_times) - first) if done_times and first is not None else None
    runs = []
    for name in sorted(store.names(state.runs)):
        if not name.endswith(".json"):
            continue
        rec = read_record(join(str(state.runs), name), {"type": "object"}, "batch run record", store=store) or {}
        s = rec.get("summary") if isinstance(rec.get("summary"), dict) else {}
        secs, n = s.get("seconds"), s.get("done")
        runs.append({"run": rec.get("run", name[:-5]), "host": rec.get("host"), "finished": rec.get("finished_utc"),
                     "done": n, "failed": s.get("failed"), "seconds": secs,
                     "items_per_hour": 3600.0 * n / secs if isinstance(secs, (int, float)) and secs > 0 and n else None})
    return {
        "folder": out, "total": len(last),
        "counts": {k: counts.get(k, 0) for k in ("pending", "running", "done", "failed")},
        "throughput": {"done": len(done_times), "span_s": span,
                       "items_per_hour": 3600.0 * len(done_times) / span if span and span > 0 else None},
        "failures": failures,
        "slowest": [{"item": line["item"], "seconds": line["seconds"], "host": line.get("host")} for line in slow],
        "runs": runs,
        "inputs_changed": _stale(last, examples) if check_inputs else None,
    }
