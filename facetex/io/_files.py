"""Input files: paths checked before anything opens them (no FIFOs, devices, empty files),
regular files read safely, and ``.npz`` members read from their headers only."""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path
from struct import error as struct_error
from zlib import error as zlib_error

import numpy as np

from ..errors import BadInputError, FacetexError, not_found_error


def _cause(e: BaseException) -> str:
    return str(e).splitlines()[0] if str(e).strip() else type(e).__name__


_FILE_KINDS = ((stat.S_ISFIFO, "a FIFO / named pipe"), (stat.S_ISCHR, "a character device"),
               (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _kind(mode: int) -> str:
    return next((name for test, name in _FILE_KINDS if test(mode)), "not a regular file")


def as_path(path, error: type = BadInputError, what: str = "file") -> Path:
    """``path`` as a Path, or ``error`` when it is not a path (None, a number, a BytesIO, a list)."""
    if isinstance(path, (str, os.PathLike)):
        return Path(path)
    hint = ": to read bytes in memory, open them with PIL.Image.open and pass that to facetex.as_image" \
        if hasattr(path, "read") else ""
    raise error(f"the {what} must be a path (str or os.PathLike), not {type(path).__name__}{hint}")


def _stat_error(path: Path, e: OSError, error: type, what: str):
    if e.errno == errno.ELOOP:
        return error("symlink loop: the path points back to itself; fix the link", path=path)
    if e.errno in (errno.ENOENT, errno.ENOTDIR):
        if os.path.islink(path):
            return error(f"broken symlink: its target does not exist ({os.readlink(path)})", path=path)
        return not_found_error(error)(f"{what} not found: check the path", path=path)
    if e.errno == errno.EACCES:
        return error(f"permission denied: cannot read this {what}", path=path)
    if e.errno == errno.ENAMETOOLONG:
        return error("file name too long", path=path)
    return error(f"cannot access this {what} ({e.strerror})", path=path)


def check_input_file(path, error: type = BadInputError, *, what: str = "file") -> Path:
    """Raise ``error`` (naming ``path``) unless it is a non-empty regular file (symlinks
    followed). FIFOs and devices are refused before anything opens them: reading a FIFO
    blocks and /dev/zero never ends."""
    path = as_path(path, error, what)
    try:
        st = os.stat(path)
    except OSError as e:
        raise _stat_error(path, e, error, what) from None
    except ValueError as e:  # NUL byte in the name
        raise error(f"invalid file name ({e})", path=path) from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"is a directory, not a file: give a {what} path", path=path)
    if not stat.S_ISREG(st.st_mode):
        raise error(f"not a regular file ({_kind(st.st_mode)}): give a {what}", path=path)
    if st.st_size == 0:
        raise error("empty file (0 bytes): re-export or replace it", path=path)
    return path


def read_regular(path, limit: int | None = None) -> bytes:
    """The bytes of ``path`` if it is a regular file, checked on the open file itself: not a
    symlink, and a FIFO is neither waited for nor read (OSError otherwise; also when it is
    larger than ``limit`` bytes)."""
    fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fh.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise OSError(errno.EINVAL, f"not a regular file ({_kind(st.st_mode)})", str(path))
        if limit is not None and st.st_size > limit:
            raise OSError(errno.EFBIG, f"larger than {limit} bytes", str(path))
        return fh.read()


def check_input_dir(path, error: type = BadInputError, *, what: str = "folder") -> Path:
    """Raise ``error`` (naming ``path``) unless it is a readable directory (symlinks followed)."""
    path = as_path(path, error, what)
    try:
        st = os.stat(path)
    except OSError as e:
        raise _stat_error(path, e, error, what) from None
    if not stat.S_ISDIR(st.st_mode):
        raise error(f"not a folder ({'a file' if stat.S_ISREG(st.st_mode) else _kind(st.st_mode)}): "
                    f"give a {what}", path=path)
    if not os.access(path, os.R_OK | os.X_OK):
        raise error(f"permission denied: cannot list this {what}", path=path)
    return path


def _check_file(path: Path, error: type) -> None:
    check_input_file(path, error)


# ------------------------------------------------------------------------------- npz
def read_npy_header(fh) -> tuple[tuple[int, ...], bool, np.dtype]:
    """(shape, fortran order, dtype) of the .npy header at ``fh``'s position (left just after
    it); a header over 10 kB is refused (numpy's ValueError)."""
    version = np.lib.format.read_magic(fh)
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, fortran, dtype = read(fh, max_header_size=10_000)
    return tuple(int(s) for s in shape), bool(fortran), dtype


def npz_members(path, error: type = BadInputError, *, what: str = "file") -> dict[str, dict]:
    """What every member of an ``.npz`` (zip) declares, read from the zip directory and the
    first bytes of each ``.npy`` member (nothing else is decompressed): name (without
    ``.npy``) -> {"dtype", "shape", "fortran", "file_size" (uncompressed bytes the zip declares),
    "compress_size"}; dtype/shape are None for a member that is not a .npy array. Raises
    ``error`` naming ``path`` when the zip or a member header is corrupt, or a member holds
    Python objects (pickles are never loaded)."""
    import tokenize
    import zipfile

    path = Path(path)
    out: dict[str, dict] = {}
    try:
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
                rec = {"dtype": None, "shape": None, "fortran": False, "file_size": int(info.file_size),
                       "compress_size": int(info.compress_size)}
                if info.filename.endswith(".npy"):
                    with zf.open(info) as fh:
                        shape, fortran, dtype = read_npy_header(fh)
                    if dtype.hasobject:
                        raise error(f"corrupt {what}: member {name!r} holds Python objects (never loaded)",
                                    path=path)
                    rec.update(dtype=dtype, shape=shape, fortran=fortran)
                out[name] = rec
    except FacetexError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, OSError, EOFError, KeyError, UnicodeDecodeError,
            SyntaxError, tokenize.TokenError, zlib_error, struct_error, RecursionError, OverflowError,
            NotImplementedError, TypeError) as e:
        raise error(f"corrupt {what} ({type(e).__name__}: {_cause(e)})", path=path) from None
    return out
