"""Scatter of short array rows by numpy's fast path (private helper).

numpy assigns ``out[index] = rows`` for (N, k) rows with small k through a per-row loop that is
several times slower than a 1-D scatter; viewing each row as one opaque scalar takes the 1-D
path with the same result.
"""

from __future__ import annotations

import numpy as np


def scatter_rows(out: np.ndarray, index: np.ndarray, rows: np.ndarray) -> None:
    """``out[index] = rows`` for a C-contiguous 2-D ``out`` and (len(index), out.shape[1])
    ``rows`` (cast to out's dtype; the last of repeated indices wins, as with fancy indexing)."""
    row = np.dtype((np.void, out.shape[1] * out.itemsize))
    out.view(row)[index, 0] = np.ascontiguousarray(rows, out.dtype).view(row)[:, 0]
