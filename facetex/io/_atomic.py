"""Atomic outputs: every output is written to a temporary file beside its final name and
then committed, exclusively unless overwriting, never onto an input; files written together
are committed together."""

from __future__ import annotations

import contextlib
import errno
import os
import re
import stat
import tempfile
import threading
from pathlib import Path
from typing import Iterator

from ..errors import FacetexError, OutputError
from ._files import _cause, _kind, as_path

_UMASK = os.umask(0o022)
os.umask(_UMASK)


# ---------------------------------------------------------------------------- writing
# Every output is written to a temporary file beside its final name and then committed:
# without overwrite by a hard link to the final name, which fails if anything appeared
# there meanwhile (an exclusive create: nothing the user did not ask to replace is ever
# replaced); with overwrite by os.replace. Files written together (an image and its
# sidecar, an .obj with its .mtl and .png) are all written first and committed together,
# the committed ones rolled back if a later one fails.

IMAGE_EXTENSIONS = {".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg", ".tif": "tiff", ".tiff": "tiff",
                    ".webp": "webp"}
_IMAGE_EXTS = IMAGE_EXTENSIONS  # old name
#: containers write_video produces (H.264, AAC audio)
VIDEO_EXTENSIONS = (".mp4", ".mov", ".m4v", ".mkv")

_COMMITTED: list[Path] = []
_SEEN_ABSENT: set[str] = set()  # outputs found absent by an earlier check of this command
_APPEARED = ("output file appeared during the run (another process?): it was not replaced; "
             "pass --overwrite to replace it")
_COMMITTED_LOCK = threading.Lock()
_NO_HARD_LINKS = {errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK, errno.EXDEV, errno.ENOSYS}


def committed_outputs(*, reset: bool = False) -> list[Path]:
    """Files committed by this process since the last reset (the CLI resets it per command
    and names them when it is interrupted: an interrupted run never claims "no output" while
    it has left intermediate files)."""
    with _COMMITTED_LOCK:
        out = list(_COMMITTED)
        if reset:
            _COMMITTED.clear()
            _SEEN_ABSENT.clear()
    return out


def _write_error(path: Path, e: OSError) -> OutputError:
    code = getattr(e, "errno", None)
    why = e.strerror or _cause(e)
    if code in (errno.ENOSPC, errno.EDQUOT):
        return OutputError(f"disk full ({why}): nothing was written; free some space or write elsewhere", path=path)
    if code == errno.EROFS:
        return OutputError("read-only file system: choose another output folder", path=path)
    if code in (errno.EACCES, errno.EPERM):
        return OutputError(f"permission denied ({why}): choose another output folder", path=path)
    if code == errno.ENOENT:
        return OutputError("the output folder disappeared during the run (deleted?): create it again or "
                           "choose another", path=path)
    if code == errno.EFBIG:
        return OutputError("file too large for this file system: choose another output folder", path=path)
    return OutputError(f"cannot write the output ({why})", path=path)


def _same_file(a, b) -> bool:
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def _check_existing(path: Path, st: os.stat_result, inputs) -> None:
    """Refusals whatever ``overwrite`` says: a directory, a device / FIFO, an input."""
    if stat.S_ISDIR(st.st_mode):
        raise OutputError("output path is a directory: give a file name", path=path)
    if not stat.S_ISREG(st.st_mode):
        raise OutputError(f"output path is {_kind(st.st_mode)}, not a regular file: it is never replaced; "
                          "give a file name", path=path)
    for i in inputs or ():
        if i is not None and _same_file(path, i):
            raise OutputError(f"output is the same file as the input {i}: it would be destroyed; "
                              "choose another output name", path=path)


def check_output_path(path, *, overwrite: bool = False, inputs=(), extensions=None,
                      what: str = "output") -> Path:
    """Raise OutputError unless ``path`` can be written: its folder exists, is a folder and is
    writable; the path is not a directory, device or FIFO, not the same file as any of
    ``inputs`` (whatever ``overwrite`` says) and absent unless ``overwrite``; its extension
    (lower case) is one of ``extensions`` when given."""
    path = as_path(path, OutputError, what)

    def check_extension():
        if extensions is not None and path.suffix.lower() not in extensions:
            raise OutputError(f"unknown {what} extension {path.suffix or '(none)'!r}: use one of "
                              f"{', '.join(sorted(extensions))}", path=path)

    folder = path.parent
    try:
        fst = os.stat(folder)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise OutputError(f"output folder {folder} is a symlink loop: fix the link", path=path) from None
        if e.errno == errno.ENOTDIR:
            raise OutputError(f"{folder} is not a folder: choose another output path", path=path) from None
        raise OutputError(f"output folder {folder} does not exist: create it first", path=path) from None
    if not stat.S_ISDIR(fst.st_mode):
        raise OutputError(f"{folder} is a file, not a folder: choose another output path", path=path)
    if fst.st_nlink == 0:  # the (current) folder was deleted while we are in it
        raise OutputError(f"output folder {os.path.abspath(folder) if str(folder) != '.' else '(the current folder)'}"
                          " was deleted: create it again or change to an existing folder", path=path)
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"output folder {folder} is not writable: choose another folder", path=path)
    try:
        os.lstat(path)
    except FileNotFoundError:
        check_extension()
        with _COMMITTED_LOCK:
            _SEEN_ABSENT.add(os.path.abspath(path))
        return path
    except OSError as e:
        raise OutputError(f"cannot use this output path ({e.strerror})", path=path) from None
    try:
        st = os.stat(path)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise OutputError("output path is a symlink loop: remove it or choose another name", path=path) from None
        st = None  # a dangling symlink: the link itself is what would be replaced
    if st is not None:
        _check_existing(path, st, inputs)
    check_extension()
    if not overwrite:
        if os.path.abspath(path) in _SEEN_ABSENT:
            raise OutputError(_APPEARED, path=path)
        raise OutputError("output file exists: pass --overwrite to replace it", path=path)
    return path


def check_outputs(paths, *, overwrite: bool = False, inputs=()) -> list[Path]:
    """:func:`check_output_path` for every path, and no two of them the same."""
    out = [check_output_path(p, overwrite=overwrite, inputs=inputs) for p in paths]
    seen = set()
    for p in out:
        key = os.path.abspath(p)
        if key in seen:
            raise OutputError("the same output path is given twice: choose distinct names", path=p)
        seen.add(key)
    return out


_TEMP_TAG = ""  # see temp_tag()


@contextlib.contextmanager
def temp_tag(tag: str | None) -> Iterator[None]:
    """Temporary files made inside (by any thread) are named ``.<stem>.<tag>.<random><ext>``:
    a batch run puts its own tag there, so that it removes only temporaries it made, never a
    user's hidden file that merely looks like one."""
    global _TEMP_TAG
    if tag and not re.fullmatch(r"[A-Za-z0-9]+", tag):
        raise ValueError(f"a temporary-file tag is letters and digits, not {tag!r}")
    old, _TEMP_TAG = _TEMP_TAG, tag or ""
    try:
        yield
    finally:
        _TEMP_TAG = old


def _temp_beside(path: Path) -> Path:
    prefix = f".{path.stem}.{_TEMP_TAG}." if _TEMP_TAG else f".{path.stem}."
    try:
        fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=path.suffix, dir=path.parent)
    except OSError as e:
        raise _write_error(path, e) from None
    os.close(fd)
    return Path(tmp)


def _write_bytes(path: Path, data: bytes) -> None:
    with open(path, "wb") as fh:
        fh.write(data)


def _link_new(tmp: Path, final: Path) -> None:
    """Give ``tmp`` the name ``final`` only if nothing has that name (FileExistsError otherwise)."""
    try:
        os.link(tmp, final)
    except FileExistsError:
        raise
    except OSError as e:
        if e.errno not in _NO_HARD_LINKS:
            raise
        # a file system without hard links (FAT, some FUSE): claim the name exclusively,
        # then rename over our own claim
        os.close(os.open(final, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666 & ~_UMASK))
        os.replace(tmp, final)
    else:
        os.unlink(tmp)


def _commit(pairs, *, overwrite: bool, inputs=()) -> None:
    """Move every (tmp, final) pair into place, in order; all or none."""
    done: list[tuple[Path, Path | None]] = []
    final = None
    try:
        for tmp, final in pairs:
            os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600 files
            backup = None
            if overwrite:
                with contextlib.suppress(FileNotFoundError):
                    st = os.stat(final)
                    _check_existing(final, st, inputs)  # a FIFO or an input may have appeared
                if os.path.lexists(final):
                    backup = Path(tempfile.mktemp(prefix=f".{final.stem}.", suffix=".old", dir=final.parent))
                    try:
                        os.link(final, backup, follow_symlinks=False)
                    except OSError:
                        backup = None  # no hard links here: a failed commit cannot restore it
                os.replace(tmp, final)
            else:
                _link_new(tmp, final)
            done.append((final, backup))
    except BaseException as e:
        for f, backup in reversed(done):
            with contextlib.suppress(OSError):
                if backup is not None:
                    os.replace(backup, f)
                else:
                    os.unlink(f)
        if isinstance(e, FacetexError):  # already one line naming the file (OutputError is an OSError)
            raise
        if isinstance(e, FileExistsError):
            raise OutputError(_APPEARED, path=final) from None
        if isinstance(e, OSError):
            raise _write_error(final, e) from None
        raise
    for f, backup in done:
        if backup is not None:
            with contextlib.suppress(OSError):
                os.unlink(backup)
    with _COMMITTED_LOCK:
        _COMMITTED.extend(f for f, _ in done)
        _SEEN_ABSENT.difference_update(os.path.abspath(f) for f, _ in done)  # ours now: "exists" next time


def write_files(items, *, overwrite: bool = False, inputs=(), reverse_commit: bool = False) -> list[Path]:
    """Write several outputs as one: ``items`` maps each path to its content (bytes, str,
    or a callable writing the given temporary path). All paths are checked
    (:func:`check_output_path`), all contents written to temporary files beside them, then
    all committed (exclusive create unless ``overwrite``); on any failure nothing new is
    left and nothing replaced. Returns the paths. ``reverse_commit``: move the files into
    place last written first (a sidecar written after its output but committed before it, so
    that a process killed mid-commit leaves the sidecar, never an output without one)."""
    items = list(items.items()) if isinstance(items, dict) else list(items)
    paths = check_outputs([p for p, _ in items], overwrite=overwrite, inputs=inputs)
    temps: list[Path] = []
    try:
        for path, (_, content) in zip(paths, items):
            tmp = _temp_beside(path)
            temps.append(tmp)
            try:
                if callable(content):
                    content(tmp)
                else:
                    _write_bytes(tmp, content.encode("utf-8") if isinstance(content, str) else bytes(content))
            except FacetexError:
                raise
            except OSError as e:
                raise _write_error(path, e) from None
        pairs = list(zip(temps, paths))
        _commit(pairs[::-1] if reverse_commit else pairs, overwrite=overwrite, inputs=inputs)
    finally:
        for t in temps:
            with contextlib.suppress(OSError):
                t.unlink()
    return paths


@contextlib.contextmanager
def atomic_path(path, *, overwrite: bool = True, inputs=()) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same extension); on success move it to
    ``path`` (os.replace with ``overwrite``, else an exclusive create that fails if ``path``
    exists); delete it on any exception (KeyboardInterrupt too). OSErrors become OutputError."""
    path = Path(path)
    tmp = _temp_beside(path)
    try:
        try:
            yield tmp
        except FacetexError:
            raise
        except OSError as e:
            raise _write_error(path, e) from None
        _commit([(tmp, path)], overwrite=overwrite, inputs=inputs)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()
