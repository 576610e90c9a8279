"""Digests of batch items' inputs, so that a rerun recomputes an item whose input was replaced
under the same name (issue 23) instead of calling it done.

A file's digest is the sha256 of its bytes, read in 1 MiB blocks. A folder's (a persona item's
photos) is the sha256 of the sorted lines ``<name>\\0<sha256 of the file>\\n`` of its files, not
hidden and not in subfolders: the files ``build_persona`` reads, and the value the item's
sidecar records as ``sha256_of_files``. Inputs at fsspec URLs are read the same way, in blocks.
:class:`InputDigests` hashes each input once per run, however many items share it (a style in
50 pairs), and never from a cache kept across runs: a file replaced with the same size and
modification time (``cp -p``) must still count as changed.
"""

from __future__ import annotations

import os
from typing import Iterable

from .._provenance import folder_sha256, sha256_stream
from ..errors import BadInputError
from ._store import _filesystem, _strip, is_url, name_of

__all__ = ["InputDigests", "file_sha256", "folder_sha256", "digests_differ"]


def file_sha256(path) -> str:
    """Hex sha256 of the bytes of the file at ``path`` (a local path or an fsspec URL)."""
    if is_url(path):
        fs = _filesystem(str(path))
        with fs.open(_strip(fs, path), "rb") as fh:
            return sha256_stream(fh)
    with open(path, "rb") as fh:
        return sha256_stream(fh)


def digests_differ(record: dict | None, digests: dict) -> bool:
    """Whether ``record`` (a manifest line, item record or sidecar's ``batch``) names input
    digests other than ``digests``. A record without them (made before batches kept them)
    has not changed: such an item stays done, as before."""
    recorded = record.get("input_digests") if isinstance(record, dict) else None
    return isinstance(recorded, dict) and recorded != digests


class InputDigests:
    """sha256 of input files and folders, each computed once (the life of one run).
    ``hashed`` counts the files read."""

    def __init__(self):
        self._cache: dict[str, str] = {}
        self.hashed = 0

    def _file(self, path: str) -> str:
        digest = self._cache.get(path)
        if digest is None:
            digest = self._cache[path] = file_sha256(path)
            self.hashed += 1
        return digest

    def _folder_files(self, path: str) -> list[tuple[str, str]] | None:
        """``(name, path)`` of the folder's files, or None when ``path`` is not a folder."""
        if is_url(path):
            fs = _filesystem(path)
            info = fs.info(_strip(fs, path))
            if info.get("type") != "directory":
                return None
            proto = path.split("://", 1)[0]
            entries = fs.ls(_strip(fs, path), detail=True)
            files = [f"{proto}://{e['name']}" for e in entries if e.get("type") == "file"]
            return [(name_of(f), f) for f in files if not name_of(f).startswith(".")]
        if not os.path.isdir(path):
            return None
        return [(e.name, e.path) for e in os.scandir(path) if e.is_file() and not e.name.startswith(".")]

    def __call__(self, path) -> str:
        """The digest of the file or folder at ``path``; BadInputError when it cannot be read."""
        path = str(path)
        digest = self._cache.get(path)
        if digest is not None:
            return digest
        try:
            files = self._folder_files(path)
            if files is None:
                return self._file(path)
            digest = self._cache[path] = folder_sha256((n, self._file(f)) for n, f in files)
            return digest
        except OSError as e:
            raise BadInputError(f"cannot read this input to check whether it changed ({e.strerror or e})",
                                path=path) from None

    def of(self, inputs: Iterable) -> dict[str, str]:
        """``{input: digest}`` of an item's inputs."""
        return {str(p): self(p) for p in inputs}
