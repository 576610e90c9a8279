"""Item claims that hold across processes and hosts sharing an output folder.

A claim is a file ``<folder>/<key>.<generation>`` created exclusively (``O_CREAT | O_EXCL``;
on object storage a conditional put, ``If-None-Match: *``): of several processes (on one host
or on several hosts sharing the folder over NFS or an object store) exactly one creates it. Its holder refreshes the file's modification time
while the item runs (:meth:`Claims.heartbeat`; on object storage it writes the object again); a claim whose time is older than ``timeout``
seconds, or whose holder is a process of this host that no longer exists, has *expired*.
An expired claim is never deleted by the next claimer (two claimers could then both
"take over"): the next claimer exclusively creates the *next generation* ``<key>.<n+1>``
instead, so there is always exactly one winner. The holder removes its generation and the
older ones when it is done.

Clocks of the hosts must agree to within ``timeout`` (NTP); the default timeout is generous.
This is hand-written: file locks (``fcntl``) do not hold across NFS clients reliably and
leave nothing to inspect after a crash.
"""

from __future__ import annotations

import json
import os
import socket
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

from .._schema import nullable
from ._state import read_record
from ._store import Store, join, store_for

__all__ = ["Claims", "Claim", "run_id"]

_HOST = socket.gethostname()
CLAIM = {"type": "object", "properties": {"run": {"type": "string"}, "host": {"type": "string"},
                                          "pid": {"type": "integer"}, "pid_start": nullable({"type": "string"})}}


def run_id() -> str:
    """A unique id of this run: UTC time, host, pid, random suffix."""
    return f"{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}-{_HOST}-{os.getpid()}-{uuid.uuid4().hex[:6]}"


def _proc_start(pid: int) -> str | None:
    """The start time of a process of this host (Linux ``/proc``), to tell a reused pid apart."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            return fh.read().rsplit(b")", 1)[1].split()[19].decode()
    except (OSError, IndexError):
        return None


def _alive(pid: int, start: str | None) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return start is None or _proc_start(pid) in (None, start)


@dataclass
class Claim:
    key: str
    path: Path | str  # a URL on object storage
    generation: int


class Claims:
    """Claims of items in ``folder`` by this process (run ``run``)."""

    def __init__(self, folder, *, timeout: float = 300.0, run: str | None = None, store: Store | None = None):
        self.folder = str(folder)  # made by the caller before the first acquire()
        self.store = store or store_for(folder)
        self.timeout = float(timeout)
        self.run = run or run_id()
        self._me = {"run": self.run, "host": _HOST, "pid": os.getpid(), "pid_start": _proc_start(os.getpid())}
        self.held: dict[str, Claim] = {}

    def _path(self, key: str, gen: int):
        p = join(self.folder, f"{key}.{gen}")
        return p if self.store.remote else Path(p)

    def _exists(self, key: str, gen: int) -> bool:
        return self.store.exists(self._path(key, gen))

    def claimed(self) -> set[str]:
        """Keys with a claim file now (one listing of the folder)."""
        return {n.rsplit(".", 1)[0] for n in self.store.names(self.folder) if "." in n and not n.startswith(".")}

    def _current(self, key: str) -> int:
        """Highest existing generation of ``key`` (-1: none)."""
        gen = -1
        while self._exists(key, gen + 1):
            gen += 1
        # a holder removes its generation and the older ones: look a little past a gap
        for g in range(gen + 2, gen + 4):
            if self._exists(key, g):
                return self._current_from(key, g)
        return gen

    def _current_from(self, key: str, gen: int) -> int:
        while self._exists(key, gen + 1):
            gen += 1
        return gen

    def holder(self, key: str) -> dict | None:
        """Who holds ``key`` now (``{run, host, pid, age_s, expired}``), or None when free."""
        gen = self._current(key)
        if gen < 0:
            return None
        p = self._path(key, gen)
        try:
            mtime = self.store.mtime(p)
        except FileNotFoundError:
            return None
        # empty or cut short: being written by its claimer (it expires by its age if that died)
        info = read_record(p, CLAIM, "batch claim", tolerate_partial=True, store=self.store)
        if info is None:
            return None
        info = dict(info, generation=gen, age_s=max(0.0, time.time() - mtime))
        info["expired"] = self._expired(info)
        return info

    def _expired(self, info: dict) -> bool:
        if info.get("age_s", 0.0) > self.timeout:
            return True
        if info.get("host") == _HOST and isinstance(info.get("pid"), int):
            return not _alive(info["pid"], info.get("pid_start"))
        return False

    def acquire(self, key: str) -> Claim | None:
        """Claim ``key``: the Claim, or None when another live process holds it."""
        if key in self.held:
            return self.held[key]
        for _ in range(8):  # a generation may be created between our look and our create
            gen = self._current(key)
            if gen >= 0:
                info = self.holder(key)
                if info is not None and info["generation"] == gen and not info["expired"]:
                    return None
            path = self._path(key, gen + 1)
            me = dict(self._me, claimed_utc=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
            try:
                self.store.create(path, json.dumps(me).encode("utf-8"))
            except FileExistsError:
                continue
            claim = Claim(key, path, gen + 1)
            self.held[key] = claim
            return claim
        return None

    def heartbeat(self) -> None:
        """Refresh every held claim (its modification time), so it does not expire."""
        for c in list(self.held.values()):
            try:
                self.store.touch(c.path)
            except FileNotFoundError:  # removed by hand: claim it again
                try:
                    self.store.create(c.path, b"")
                except OSError:
                    pass
            except OSError:
                pass

    def release(self, key: str) -> None:
        """Give ``key`` up: remove our generation and the (expired) older ones."""
        c = self.held.pop(key, None)
        if c is None:
            return
        for g in range(c.generation, -1, -1):
            try:
                self.store.remove(self._path(key, g))
            except OSError:
                break

    def release_all(self) -> None:
        for k in list(self.held):
            self.release(k)
