"""Where a batch folder and its inputs live: a local (or NFS) folder, or any fsspec URL
(``s3://``, ``gs://``, ``az://``, ...; ``pip install 'facetex[s3]'`` for S3).

A :class:`Store` offers the few operations the batch state needs, with the same meaning on
both kinds: ``create`` is an *exclusive* create (``O_EXCL`` locally; on object storage a
conditional put, ``If-None-Match: *``, which S3 and S3-compatible servers honour), ``put``
replaces a file as one (a rename locally; a single PUT on object storage, which is atomic),
``append`` adds to the end (``O_APPEND`` locally; object storage has no append: fsspec
rewrites the object, so only one run should write a remote folder's manifest at a time).

Workers never write into object storage while they compute: :func:`run_staged_item` downloads
the item's remote inputs into a local cache, runs the item on local paths in a temporary
folder, then uploads its files with exclusive creates, the sidecar first and the output last,
so the output is the item's completion marker (as the local commit moves the sidecar first).
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from ..errors import BadInputError, FacetexError, OutputError

__all__ = ["is_url", "join", "name_of", "parent_of", "Store", "LocalStore", "FsspecStore", "store_for",
           "run_staged_item", "fetch", "list_files", "read_input_bytes", "STAGED_FN"]

_URL = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]*://")
STAGED_FN = "_staged_fn"


def is_url(path) -> bool:
    """Whether ``path`` is an fsspec URL (``s3://b/k``, ``gs://...``); ``file://`` counts as local."""
    s = str(path)
    return bool(_URL.match(s)) and not s.startswith("file://")


def join(base, *parts: str) -> str:
    """``base/part/...`` for a local folder or a URL."""
    if is_url(base):
        return "/".join([str(base).rstrip("/"), *(p.strip("/") for p in parts)])
    return str(Path(base, *parts))


def name_of(path) -> str:
    return str(path).rstrip("/").rsplit("/", 1)[-1] if is_url(path) else Path(path).name


def parent_of(path) -> str:
    return str(path).rstrip("/").rsplit("/", 1)[0] if is_url(path) else str(Path(path).parent)


def _filesystem(url: str):
    """The fsspec filesystem of ``url`` (listings not cached: other runs change the folder)."""
    try:
        import fsspec
    except ImportError:  # pragma: no cover - fsspec comes with torch
        raise BadInputError(f"{url}: URLs need fsspec: pip install fsspec") from None
    protocol = str(url).split("://", 1)[0]
    try:
        cls = fsspec.get_filesystem_class(protocol)
    except (ImportError, ValueError) as e:
        extra = " (pip install 'facetex[s3]')" if protocol in ("s3", "s3a") else ""
        raise BadInputError(f"{url}: cannot use {protocol}:// URLs: {e}{extra}".replace("\n", " ")) from None
    return cls(use_listings_cache=False, skip_instance_cache=False)


def _strip(fs, url: str) -> str:
    return fs._strip_protocol(str(url))


class Store:
    """The operations of a batch folder's storage (see the module docstring)."""

    remote = False

    def exists(self, path) -> bool: ...

    def read(self, path, limit: int | None = None) -> bytes: ...

    def create(self, path, data: bytes) -> None: ...

    def put(self, path, data: bytes) -> None: ...

    def append(self, path, data: bytes) -> None: ...

    def remove(self, path) -> None: ...

    def mtime(self, path) -> float: ...

    def touch(self, path) -> None: ...

    def names(self, folder) -> set[str]: ...

    def makedirs(self, path) -> None: ...

    def isdir(self, path) -> bool: ...


class LocalStore(Store):
    """A local or NFS folder (exclusive creates and renames are what NFS honours)."""

    def exists(self, path) -> bool:
        return os.path.lexists(path)

    def read(self, path, limit=None) -> bytes:
        from ..io import read_regular

        return read_regular(path, limit=limit)

    def create(self, path, data: bytes) -> None:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)

    def put(self, path, data: bytes) -> None:
        from ..io import atomic_path

        with atomic_path(path) as tmp:
            Path(tmp).write_bytes(data)

    def append(self, path, data: bytes) -> None:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW | os.O_NONBLOCK, 0o644)
        try:
            os.write(fd, data)  # one write: lines of concurrent runs on this host do not interleave
        finally:
            os.close(fd)

    def remove(self, path) -> None:
        try:
            os.unlink(path)
        except FileNotFoundError:
            pass

    def mtime(self, path) -> float:
        return os.lstat(path).st_mtime

    def touch(self, path) -> None:
        os.utime(path)

    def names(self, folder) -> set[str]:
        try:
            return {e.name for e in os.scandir(folder)}
        except (FileNotFoundError, NotADirectoryError):
            return set()

    def makedirs(self, path) -> None:
        Path(path).mkdir(parents=True, exist_ok=True)

    def isdir(self, path) -> bool:
        return os.path.isdir(path)


class FsspecStore(Store):
    """A folder at an fsspec URL. Credentials and endpoints come from the usual places of the
    backend (for S3: ``AWS_*`` variables, ``~/.aws``, ``AWS_ENDPOINT_URL`` for an S3-compatible server)."""

    remote = True

    def __init__(self, url: str):
        self.url = str(url).rstrip("/")
        self.fs = _filesystem(self.url)

    def _p(self, path) -> str:
        return _strip(self.fs, path)

    def exists(self, path) -> bool:
        return bool(self.fs.exists(self._p(path)))

    def read(self, path, limit=None) -> bytes:
        data = self.fs.cat_file(self._p(path))
        if limit is not None and len(data) > limit:
            raise OSError(errno.EFBIG, f"larger than {limit} bytes", str(path))
        return data

    def create(self, path, data: bytes) -> None:
        try:
            with self.fs.open(self._p(path), "xb") as fh:
                fh.write(data)
        except ValueError as e:  # the backend has no exclusive create
            raise OutputError(f"this storage cannot create files exclusively ({e}), which a batch needs",
                              path=path) from None

    def put(self, path, data: bytes) -> None:
        self.fs.pipe_file(self._p(path), data)

    def append(self, path, data: bytes) -> None:
        with self.fs.open(self._p(path), "ab") as fh:
            fh.write(data)

    def remove(self, path) -> None:
        try:
            self.fs.rm_file(self._p(path))
        except FileNotFoundError:
            pass

    def mtime(self, path) -> float:
        info = self.fs.info(self._p(path))
        t = info.get("LastModified") or info.get("mtime") or info.get("updated") or info.get("last_modified")
        if t is None:
            return self.fs.modified(self._p(path)).timestamp()
        if isinstance(t, str):
            from datetime import datetime

            return datetime.fromisoformat(t.replace("Z", "+00:00")).timestamp()
        return t.timestamp() if hasattr(t, "timestamp") else float(t)

    def touch(self, path) -> None:
        p = self._p(path)
        self.fs.pipe_file(p, self.fs.cat_file(p))  # a new object: a new modification time

    def names(self, folder) -> set[str]:
        try:
            return {str(e).rstrip("/").rsplit("/", 1)[-1] for e in self.fs.ls(self._p(folder), detail=False)}
        except (FileNotFoundError, NotADirectoryError):
            return set()

    def makedirs(self, path) -> None:
        try:
            self.fs.makedirs(self._p(path), exist_ok=True)
        except FileExistsError:
            pass

    def isdir(self, path) -> bool:
        return bool(self.fs.isdir(self._p(path)))

    def check_exclusive(self, folder) -> None:
        """Refuse (one line) a store that does not honour exclusive creates (a server that
        ignores ``If-None-Match``, a backend that treats ``xb`` as ``wb``): two runs could then
        replace each other's outputs and claims. Costs three requests."""
        import uuid

        probe = join(folder, f".facetex-exclusive-probe-{uuid.uuid4().hex[:12]}")
        self.create(probe, b"1")
        try:
            self.create(probe, b"2")
        except FileExistsError:
            return
        finally:
            self.remove(probe)
        raise OutputError("this storage does not honour exclusive creates (If-None-Match: *), which a batch needs so "
                          "that no run replaces another's output: use S3 or a store that does, or a shared folder",
                          path=folder)

    def upload(self, local, path, *, exclusive: bool = True) -> None:
        with open(local, "rb") as src, self.fs.open(self._p(path), "xb" if exclusive else "wb") as dst:
            shutil.copyfileobj(src, dst, 8 * 2**20)


def store_for(path) -> Store:
    """The store of a batch folder (local path or URL)."""
    return FsspecStore(str(path)) if is_url(path) else LocalStore()


# ------------------------------------------------------------------------------------ inputs
def list_files(url: str) -> list[str]:
    """The files directly in the folder at ``url`` (URLs, sorted); BadInputError when there is none."""
    fs = _filesystem(url)
    proto = str(url).split("://", 1)[0]
    try:
        entries = fs.ls(_strip(fs, url), detail=True)
    except FileNotFoundError:
        raise BadInputError("no such folder", path=url) from None
    except OSError as e:
        raise BadInputError(f"cannot list it ({e})", path=url) from None
    return sorted(f"{proto}://{e['name']}" for e in entries if e.get("type") == "file")


def read_input_bytes(url: str, limit: int = 64 * 2**20) -> bytes:
    fs = _filesystem(url)
    try:
        data = fs.cat_file(_strip(fs, url))
    except FileNotFoundError:
        raise BadInputError("no such file", path=url) from None
    except OSError as e:
        raise BadInputError(f"cannot read it ({e})", path=url) from None
    if len(data) > limit:
        raise BadInputError(f"larger than {limit} bytes", path=url)
    return data


def check_remote_input(url: str, what: str = "file") -> None:
    fs = _filesystem(url)
    try:
        info = fs.info(_strip(fs, url))
    except FileNotFoundError:
        raise BadInputError(f"no such {what}", path=url) from None
    except OSError as e:
        raise BadInputError(f"cannot read this {what} ({e})", path=url) from None
    if info.get("type") != "file":
        raise BadInputError(f"not a file: give a {what}", path=url)


def cache_dir() -> Path:
    """Where workers keep downloaded inputs: ``$FACETEX_CACHE/batch-inputs`` (default
    ``~/.cache/facetex``)."""
    root = os.environ.get("FACETEX_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "facetex")
    return Path(root) / "batch-inputs"


def fetch(url: str, digest: str | None = None) -> str:
    """A local copy of the remote file or folder ``url``, kept in :func:`cache_dir` under a
    name made of the URL, the object's ETag / size / time and ``digest`` (its sha256 as the run
    hashed it: an object replaced by one of the same size is fetched again on a store without
    ETags, such as ``memory://``)."""
    fs = _filesystem(url)
    p = _strip(fs, url)
    info = fs.info(p)
    stamp = json.dumps([url, info.get("ETag") or info.get("etag"), info.get("size"), str(info.get("LastModified"))]
                       + ([digest] if digest else []), default=str)
    key = hashlib.sha256(stamp.encode()).hexdigest()[:20]
    name = name_of(url) or "input"
    target = cache_dir() / key / name
    if target.exists():
        return str(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".fetch-", dir=target.parent))
    try:
        if info.get("type") == "directory":
            fs.get(p.rstrip("/") + "/", str(tmp / name), recursive=True)
        else:
            fs.get_file(p, str(tmp / name))
        try:
            os.replace(tmp / name, target)  # another worker of this host may have been quicker: fine
        except OSError:
            if not target.exists():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return str(target)


def _replace_strings(obj: Any, mapping: dict[str, str]) -> Any:
    """``obj`` with every string that starts with a key of ``mapping`` given that key's value instead."""
    if isinstance(obj, str):
        for local, remote in mapping.items():
            if obj == local or obj.startswith(local.rstrip("/") + "/"):
                return remote + obj[len(local):]
        return obj
    if isinstance(obj, dict):
        return {k: _replace_strings(v, mapping) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_replace_strings(v, mapping) for v in obj]
    return obj


def run_staged_item(p: dict) -> dict:
    """Run the item function ``p[STAGED_FN]`` on local copies: remote inputs (payload values
    that are URLs, listed in ``p["_remote_inputs"]``) fetched into the cache, outputs written
    into a temporary folder, then uploaded to ``p["output"]`` (a URL) with exclusive creates,
    sidecar first, output last (the completion marker). The sidecar names the URLs, not the
    local copies. When both objects exist already (another run made the item after its claim
    expired) the item is not an error: its note says so. With ``p["batch"]["replace"]`` (its
    inputs changed since) the objects are replaced, output first, sidecar (naming the new input
    digests) last: each PUT is atomic, and an upload cut short leaves the old digests."""
    fn = p[STAGED_FN]
    remote_out = p["output"]
    store = FsspecStore(parent_of(remote_out))
    local = {k: v for k, v in p.items() if k not in (STAGED_FN, "_remote_inputs")}
    mapping: dict[str, str] = {}
    digests = (p.get("batch") or {}).get("input_digests") or {}
    for k in p.get("_remote_inputs", ()):
        local[k] = fetch(p[k], digests.get(p[k]))
        mapping[local[k]] = p[k]
    with tempfile.TemporaryDirectory(prefix="facetex-item-") as tmp:
        local["output"] = str(Path(tmp) / name_of(remote_out))
        mapping[tmp] = parent_of(remote_out)
        t0 = time.perf_counter()
        try:
            value = fn(local)
        except FacetexError as e:  # name the URL, not the local copy
            path = _replace_strings(e.path, mapping) if e.path else None
            message = e.message
            for k, v in mapping.items():
                message = message.replace(k, v)
            raise type(e)(message, path=path) from None
        files = [Path(f) for f in (value.get("outputs") if isinstance(value, dict) else None) or [local["output"]]]
        sidecars = [f for f in files if f.name.endswith(".json")]
        replace = bool((p.get("batch") or {}).get("replace"))
        ordered = sidecars + [f for f in files if f not in sidecars]  # the output last: the completion marker
        if replace:  # the old objects are there: the sidecar with the new digests is the marker
            ordered = ordered[len(sidecars):] + sidecars
        written = []
        for f in ordered:
            url = join(parent_of(remote_out), f.name)
            if f in sidecars:
                record = _replace_strings(json.loads(f.read_bytes()), mapping)
                f.write_bytes((json.dumps(record, indent=2, default=str) + "\n").encode())
            try:
                store.upload(f, url, exclusive=not replace)
            except FileExistsError:
                if all(store.exists(join(parent_of(remote_out), g.name)) for g in files):
                    return dict(value, outputs=[join(parent_of(remote_out), g.name) for g in files],
                                note="written by another run")
                for w in written:  # never half an item of ours beside another's
                    store.remove(w)
                raise OutputError("exists already (not made by this item): move it away, or choose another --out",
                                  path=url) from None
            written.append(url)
        out = dict(value) if isinstance(value, dict) else {}
        out["outputs"] = [join(parent_of(remote_out), f.name) for f in files]
        timings = out.get("timings") if isinstance(out.get("timings"), dict) else None
        if timings is not None:
            timings["upload_s"] = time.perf_counter() - t0 - float(timings.get("wall_s") or 0.0)
        return out
