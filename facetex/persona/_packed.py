"""Lossless packing of per-photo integer arrays in ``.persona`` files (format 4).

Each photo's array is stored as one zlib stream of its rows minus the row above (modulo
2^bits; the bytes of wider integers in separate planes): neighbouring rows of a photo, a
confidence map or a smooth flow are alike, so the differences are small and deflate well
(a frontalized 192 x 240 photo: 138 kB -> ~50 kB). Unpacking is one inflate and a prefix sum
over the rows (log2(rows) vector additions). Streams are written by zlib and inflated by ISA-L
(``isal``, the same deflate format, 2.4x faster on these streams: 0.17 s instead of 0.40 s for a
520-photo persona's aligned photos) when it is installed, else by zlib.
"""

from __future__ import annotations

import zlib
from concurrent.futures import ThreadPoolExecutor

import numpy as np

try:  # ISA-L's zlib: the same streams and checksums, faster (a dependency; zlib where it has no wheel)
    from isal import isal_zlib as fast_zlib
except ImportError:  # pragma: no cover - isal ships wheels for the platforms facetex supports
    fast_zlib = zlib

#: deflate level of the packed streams (inflating costs the same at any level; measured on 192 x 240
#: photos: level 2 packs in 3 ms at 57 kB, level 6 in 13 ms at 51 kB)
PACK_LEVEL = 2


def _unsigned(dtype: np.dtype) -> np.dtype:
    """The little-endian unsigned integer dtype of ``dtype``'s size (wrap-around arithmetic)."""
    return np.dtype(f"<u{np.dtype(dtype).itemsize}")


class Packed:
    """n integer arrays of one shape, packed (see the module docstring).

    ``blob``: (total,) uint8, the streams one after the other; ``offsets``: (n + 1,) int64, photo
    i's stream is ``blob[offsets[i]:offsets[i + 1]]``; ``shape``: (n, rows, ...); ``dtype``: an
    integer dtype."""

    __slots__ = ("blob", "offsets", "shape", "dtype")

    def __init__(self, blob: np.ndarray, offsets: np.ndarray, shape, dtype):
        self.blob, self.offsets = blob, offsets
        self.shape, self.dtype = tuple(int(s) for s in shape), np.dtype(dtype)
        if self.dtype.kind not in "iu" or len(self.shape) < 2:
            raise ValueError(f"packed arrays are integer stacks (n, rows, ...), got {self.dtype} {self.shape}")
        if self.offsets.shape != (self.shape[0] + 1,) or self.blob.ndim != 1:
            raise ValueError(f"{self.offsets.shape[0] - 1} packed streams for {self.shape[0]} photos")
        if self.offsets[0] != 0 or self.offsets[-1] != self.blob.size or np.any(np.diff(self.offsets) < 0):
            raise ValueError("packed stream offsets out of order or outside the data")

    def __len__(self) -> int:
        return self.shape[0]

    @property
    def nbytes(self) -> int:
        return int(self.blob.nbytes + self.offsets.nbytes)

    @classmethod
    def pack(cls, stack: np.ndarray, level: int = PACK_LEVEL, *, workers: int = 1) -> "Packed":
        """Pack an (n, rows, ...) integer stack (on ``workers`` threads)."""
        stack = np.ascontiguousarray(stack)
        n, rows = stack.shape[:2]
        u = stack.view(_unsigned(stack.dtype)).reshape(n, rows, -1)

        def one(x):
            d = x.copy()
            d[1:] -= x[:-1]  # modulo 2^bits (unsigned)
            planes = d.view(np.uint8).reshape(-1, d.itemsize).T  # byte planes of wider integers
            return zlib.compress(np.ascontiguousarray(planes).tobytes(), level)

        if workers <= 1 or n < 8:
            streams = [one(x) for x in u]
        else:
            with ThreadPoolExecutor(workers) as pool:
                streams = list(pool.map(one, u))
        offsets = np.zeros(n + 1, np.int64)
        offsets[1:] = np.cumsum([len(s) for s in streams])
        blob = np.frombuffer(b"".join(streams), np.uint8).copy() if streams else np.zeros(0, np.uint8)
        return cls(blob, offsets, stack.shape, stack.dtype)

    def photo(self, i: int, out: np.ndarray | None = None) -> np.ndarray:
        """Photo i's array (into ``out`` when given); ValueError or zlib.error when its stream is
        corrupt (wrong length, trailing data)."""
        shape = self.shape[1:]
        out = np.empty(shape, self.dtype) if out is None else out
        nbytes = int(np.prod(shape)) * self.dtype.itemsize
        d = fast_zlib.decompressobj()
        try:
            raw = d.decompress(self.blob[self.offsets[i]:self.offsets[i + 1]], nbytes)
        except fast_zlib.error as e:  # ISA-L's error is not zlib's: one type for the callers
            raise zlib.error(f"packed photo {i}: {e}") from None
        if len(raw) != nbytes or not d.eof or d.unconsumed_tail or d.unused_data:
            raise ValueError(f"packed photo {i} does not hold {nbytes} bytes")
        u = out.view(_unsigned(self.dtype)).reshape(shape[0], -1)
        planes = np.frombuffer(raw, np.uint8).reshape(self.dtype.itemsize, -1)
        if self.dtype.itemsize == 1:
            u.reshape(-1)[...] = planes[0]
        else:
            u.view(np.uint8).reshape(-1, self.dtype.itemsize)[...] = planes.T
        k = 1
        while k < len(u):  # prefix sum over the rows (Hillis-Steele; numpy buffers the overlap)
            u[k:] += u[:-k]
            k *= 2
        return out

    def unpack(self, *, workers: int = 1) -> np.ndarray:
        """The (n, rows, ...) stack (photos unpacked on ``workers`` threads: zlib and numpy
        release the GIL)."""
        out = np.empty(self.shape, self.dtype)
        idx = range(len(self))
        if workers <= 1 or len(self) < 8:
            for i in idx:
                self.photo(i, out[i])
        else:
            with ThreadPoolExecutor(workers) as pool:
                list(pool.map(lambda i: self.photo(i, out[i]), idx))
        return out
