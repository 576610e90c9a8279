"""Uploads into a job's folder: size limits, names the studio chooses, checked contents.

A request's file name is used for two things only: its extension, looked up in a fixed table
(it picks which of the studio's own names the file is saved under: ``content.jpg``,
``photos/photo_007.png``), and, made printable and short, the name shown in messages. No
string from a request is ever joined into a path. Zip archives are read member by member
(never extracted by their names), with limits on the count and the total size of the photos.
"""

from __future__ import annotations

import zipfile
from pathlib import Path, PurePosixPath, PureWindowsPath

from ..errors import BadImageError, BadInputError, FacetexError

#: images a browser shows and facetex reads (TIFF is left out: the pages show the uploads)
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".webp")
#: driver clips facetex reads (PyAV)
VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".avi", ".mpg", ".mpeg", ".webm")
#: most photos a persona upload may hold
MAX_PHOTOS = 400
CHUNK = 1 << 20


class UploadTooLargeError(FacetexError):
    """An upload is larger than the studio's limit (``facetex serve --max-upload-mb``)."""


def shown_name(filename: str | None, default: str = "upload") -> str:
    """The base name of a client's file name, printable and at most 80 characters: for
    messages only, never for a path."""
    name = PureWindowsPath(PurePosixPath(filename or "").name).name  # either separator
    name = "".join(c for c in name if c.isprintable())[:80]
    return name or default


def suffix_of(filename: str | None, allowed: tuple[str, ...], what: str) -> str:
    """The extension of ``filename`` when it is one of ``allowed`` (lower case), else
    BadInputError naming the file and the extensions accepted."""
    suffix = PurePosixPath(shown_name(filename)).suffix.lower()
    if suffix not in allowed:
        raise BadInputError(f"{shown_name(filename)}: not {what} (use {', '.join(allowed)})")
    return suffix


async def save_upload(upload, dest: Path, limit: int) -> int:
    """Copy an uploaded file (Starlette's ``UploadFile``) to ``dest`` in chunks; more than
    ``limit`` bytes removes it and raises :class:`UploadTooLargeError`. Returns the size."""
    size = 0
    with open(dest, "xb") as fh:
        while chunk := await upload.read(CHUNK):
            size += len(chunk)
            if size > limit:
                fh.close()
                dest.unlink(missing_ok=True)
                raise UploadTooLargeError(f"{shown_name(upload.filename)}: larger than the studio's upload limit "
                                          f"of {limit / 2**20:.0f} MB")
            fh.write(chunk)
    if size == 0:
        dest.unlink(missing_ok=True)
        raise BadInputError(f"{shown_name(upload.filename)}: empty file")
    return size


def check_image(path: Path, shown: str) -> None:
    """BadImageError naming ``shown`` unless ``path`` decodes as an image (the server's path
    is not in the message)."""
    from ..io import read_image

    try:
        read_image(path, reduce_to=4_000_000)
    except FacetexError as e:
        raise BadImageError(f"{shown}: {e.message}") from None


def check_persona(path: Path, shown: str) -> None:
    """BadInputError naming ``shown`` unless ``path`` is a readable .persona file (its header)."""
    from ..persona import read_persona_header

    try:
        read_persona_header(path)
    except FacetexError as e:
        raise BadInputError(f"{shown}: {e.message}") from None


def photos_from_zip(archive: Path, folder: Path, start: int, limit: int) -> int:
    """Copy the images of a zip archive into ``folder`` as ``photo_NNN<ext>`` (numbered from
    ``start``); member names choose only the extension. At most :data:`MAX_PHOTOS` photos and
    ``limit`` bytes uncompressed in all (a zip bomb stops at the limit). Returns the count."""
    shown = archive.name
    try:
        zf = zipfile.ZipFile(archive)
    except (zipfile.BadZipFile, OSError) as e:
        raise BadInputError(f"{shown}: not a zip archive ({e})") from None
    n, total = 0, 0
    with zf:
        for info in zf.infolist():
            suffix = PurePosixPath(info.filename).suffix.lower()
            if info.is_dir() or suffix not in IMAGE_SUFFIXES or PurePosixPath(info.filename).name.startswith("."):
                continue  # other files (a readme, macOS's ._ resource forks) are skipped
            if start + n >= MAX_PHOTOS:
                raise BadInputError(f"{shown}: more than {MAX_PHOTOS} photos: give fewer")
            dest = folder / f"photo_{start + n:03d}{suffix}"
            with zf.open(info) as src, open(dest, "xb") as out:
                while chunk := src.read(CHUNK):  # counted as read: the header's sizes may lie
                    total += len(chunk)
                    if total > limit:
                        raise UploadTooLargeError(f"{shown}: its photos are larger than the studio's upload limit "
                                                  f"of {limit / 2**20:.0f} MB uncompressed")
                    out.write(chunk)
            n += 1
    return n


class BodyLimit:
    """ASGI middleware: a request body over ``limit`` bytes is refused with 413 and a one-line
    JSON error, from its Content-Length before it is read, or as soon as the bytes received pass
    the limit (a chunked upload): Starlette's form parser would otherwise spool all of it to disk
    first."""

    def __init__(self, app, limit: int):
        self.app, self.limit = app, limit

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        message = f"request larger than the studio's upload limit of {self.limit / 2**20:.0f} MB"
        length = dict(scope.get("headers") or []).get(b"content-length")
        if length is not None and length.isdigit() and int(length) > self.limit:
            return await _json_error(send, 413, message)
        seen = 0
        started = False

        async def counted():
            nonlocal seen
            msg = await receive()
            if msg["type"] == "http.request":
                seen += len(msg.get("body", b""))
                if seen > self.limit:
                    raise UploadTooLargeError(message)
            return msg

        async def tracked(msg):
            nonlocal started
            started = started or msg["type"] == "http.response.start"
            await send(msg)

        try:
            await self.app(scope, counted, tracked)
        except UploadTooLargeError:
            if not started:
                await _json_error(send, 413, message)


async def _json_error(send, status: int, message: str) -> None:
    import json

    body = json.dumps({"error": message}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]})
    await send({"type": "http.response.body", "body": body})
