"""Provenance of an output: what made it, from what, with which software.

Every output facetex writes (image, overlay, MP4, persona, OBJ, benchmark folder, report)
gets a JSON *sidecar* holding one :func:`provenance` record: the command line, the sha256
of every input file, all parameters, the seed, a UTC timestamp and the versions of
facetex and of the libraries that computed it. The sidecar of ``OUT.ext`` is
``OUT.ext.json`` (:func:`sidecar_path`); a benchmark folder's is ``run.json`` inside it.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import os
import platform
import shlex
import sys
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Mapping

if TYPE_CHECKING:
    import threading

__all__ = ["provenance", "sidecar_path", "sha256_file", "hash_in_background", "library_versions", "command_line",
           "hash_inputs", "LIBRARIES", "SCHEMA"]

#: identifies a facetex sidecar record (bumped when its layout changes)
SCHEMA = "facetex.provenance/1"

#: label -> installed distributions to try, in order (the first found wins)
LIBRARIES = {
    "torch": ("torch",),
    "numpy": ("numpy",),
    "opencv": ("opencv-python-headless", "opencv-python", "opencv-contrib-python", "opencv-contrib-python-headless"),
    "dlib": ("dlib-bin", "dlib"),
    "scipy": ("scipy",),
    "scikit-image": ("scikit-image",),
    "pyav": ("av",),
    "pillow": ("pillow",),
    "matplotlib": ("matplotlib",),
    "ai-edge-litert": ("ai-edge-litert",),
}

_CHUNK = 1 << 20
_ARGV: list[str] | None = None  # the running CLI command's argv (set by facetex.cli.main)


def set_command(argv: Iterable[str] | None) -> None:
    """Record the command line of the CLI command now running (None: use ``sys.argv``)."""
    global _ARGV
    _ARGV = None if argv is None else ["facetex", *[str(a) for a in argv]]
_HASH_CACHE: dict[tuple[str, int, int], str] = {}


def sha256_stream(fh) -> str:
    """Hex sha256 of the bytes of the open binary file ``fh``, read in blocks."""
    h = hashlib.sha256()
    for block in iter(lambda: fh.read(_CHUNK), b""):
        h.update(block)
    return h.hexdigest()


def folder_sha256(names_and_digests: Iterable[tuple[str, str]]) -> str:
    """A folder's digest from ``(name, sha256)`` of its files: the sha256 of the sorted lines
    ``<name>\0<sha256 of the file>\n`` (recorded as ``sha256_of_files``)."""
    h = hashlib.sha256()
    for name, digest in sorted(names_and_digests):
        h.update(f"{name}\0{digest}\n".encode())
    return h.hexdigest()


def sha256_file(path) -> str:
    """Hex sha256 of a file's bytes (cached per path, size and modification time)."""
    p = Path(path)
    st = p.stat()
    key = (os.path.abspath(p), st.st_size, st.st_mtime_ns)
    if key not in _HASH_CACHE:
        with open(p, "rb") as fh:
            _HASH_CACHE[key] = sha256_stream(fh)
    return _HASH_CACHE[key]


def hash_in_background(paths: Iterable) -> "threading.Thread":
    """Start hashing the files ``paths`` on a daemon thread (sha256 releases the GIL): the
    provenance written after a long run then finds them in the cache. Join it before."""
    import threading

    def work():
        for p in paths:
            try:
                if p is not None and Path(p).is_file():
                    sha256_file(p)
            except OSError:
                pass  # reported by the provenance record itself

    t = threading.Thread(target=work, name="facetex-hash", daemon=True)
    t.start()
    return t


def library_versions() -> dict[str, str | None]:
    """Versions of Python, facetex and the libraries it computes with (None: not installed).

    Read from the installed distributions' metadata, so nothing heavy (torch) is imported."""
    from . import __version__

    out: dict[str, str | None] = {"facetex": __version__, "python": platform.python_version()}
    for label, dists in LIBRARIES.items():
        out[label] = None
        for d in dists:
            try:
                out[label] = metadata.version(d)
                break
            except metadata.PackageNotFoundError:
                continue
    return out


def command_line(argv: Iterable[str] | None = None) -> str:
    """The command as a user would type it again (``facetex ...`` for the CLI)."""
    if argv is None:
        argv = _ARGV if _ARGV is not None else sys.argv
    argv = [str(a) for a in argv]
    if argv and Path(argv[0]).name in ("facetex", "__main__.py", "-m"):
        argv = ["facetex", *argv[1:]]
    return shlex.join(argv)


def _input_record(path) -> dict:
    p = Path(path)
    rec: dict[str, Any] = {"path": str(p)}
    try:
        if p.is_file():
            rec.update(sha256=sha256_file(p), bytes=p.stat().st_size)
        elif p.is_dir():
            files = [f for f in p.iterdir() if f.is_file() and not f.name.startswith(".")]
            rec.update(sha256_of_files=folder_sha256((f.name, sha256_file(f)) for f in files), files=len(files),
                       note="sha256 of the sorted lines '<name>\\0<sha256 of the file>\\n' of the folder's files")
        else:
            rec["missing"] = True
    except OSError as e:
        rec["error"] = e.strerror or type(e).__name__
    return rec


def hash_inputs(inputs: Mapping[str, Any] | Iterable | None) -> dict[str, Any]:
    """``{name: {"path", "sha256", "bytes"}}`` for every input file (a folder gets a hash of
    its files' hashes; a list of files under one name gets a list of records). Inputs given
    as in-memory arrays are recorded as ``{"array": [shape], "dtype"}``."""
    if inputs is None:
        return {}
    if not isinstance(inputs, Mapping):
        inputs = {f"input{i}": v for i, v in enumerate(inputs)}
    out: dict[str, Any] = {}
    for name, value in inputs.items():
        if value is None:
            continue
        if isinstance(value, (str, os.PathLike)):
            out[name] = _input_record(value)
        elif hasattr(value, "shape") and hasattr(value, "dtype"):
            out[name] = {"array": list(value.shape), "dtype": str(value.dtype)}
        elif isinstance(value, (list, tuple)):
            out[name] = [_input_record(v) if isinstance(v, (str, os.PathLike)) else repr(v) for v in value]
        else:
            out[name] = {"object": type(value).__name__}
    return out


def _jsonable(v):
    import dataclasses

    import numpy as np

    if isinstance(v, Mapping):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, set, frozenset)):
        return [_jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return {"array": list(v.shape), "dtype": str(v.dtype)}  # never image data in a sidecar
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, os.PathLike):
        return os.fspath(v)
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return _jsonable(dataclasses.asdict(v))
    if isinstance(v, float) and v != v:
        return None
    if v is None or isinstance(v, (str, int, float, bool)):
        return v
    return repr(v)


def provenance(*, command: str, inputs=None, params: Mapping | None = None, seed: int | None = None,
               argv: Iterable[str] | None = None, outputs: Iterable | None = None, **extra) -> dict:
    """The sidecar record of one output.

    Parameters
    ----------
    command : str
        What ran, e.g. ``"transfer"`` or ``"persona build"``.
    inputs : mapping or iterable, optional
        Input files (paths; folders and lists allowed) or in-memory arrays, by name.
    params : mapping, optional
        Every parameter of the run (dataclasses and numpy values are converted; arrays
        are recorded by shape and dtype only).
    seed : int, optional
        The random seed (None for deterministic commands that take none).
    argv : iterable of str, optional
        The command line; default ``sys.argv``.
    outputs : iterable, optional
        The files this record describes.
    **extra
        Further fields (timings, results), stored as given.

    Returns
    -------
    dict
        ``schema, command, command_line, cwd, created_utc, seed, inputs, params, outputs,
        versions, platform`` and the ``extra`` fields.
    """
    rec = {
        "schema": SCHEMA,
        "command": command,
        "command_line": command_line(argv),
        "cwd": os.getcwd(),
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "seed": seed,
        "inputs": hash_inputs(inputs),
        "params": _jsonable(dict(params or {})),
        "outputs": [str(o) for o in outputs] if outputs is not None else [],
        "versions": library_versions(),
        "platform": {"system": platform.system(), "machine": platform.machine(),
                     "cpu_count": os.cpu_count()},
    }
    for k, v in extra.items():
        rec[k] = _jsonable(v)
    return rec


def sidecar_path(output) -> Path:
    """``OUT.ext`` -> ``OUT.ext.json``; a folder -> ``FOLDER/run.json``."""
    p = Path(output)
    if p.is_dir():
        return p / "run.json"
    return p.with_name(p.name + ".json")
