"""scatter_rows: out[index] = rows through a 1-D scatter."""

import numpy as np

from facetex.puppet._rows import scatter_rows


def test_scatter_rows_equals_fancy_assignment():
    rng = np.random.default_rng(0)
    for dtype, k in ((np.float32, 3), (np.float64, 2), (np.float64, 3), (np.int64, 1)):
        ref = rng.normal(size=(50, k)).astype(dtype)
        out = ref.copy()
        idx = rng.integers(0, 50, 80)  # repeated indices: the last row written wins
        rows = rng.normal(size=(80, k))  # float64, cast to out's dtype as assignment does
        ref[idx] = rows
        scatter_rows(out, idx, rows)
        np.testing.assert_array_equal(out, ref)
        view = np.zeros((10, 4, k), dtype).reshape(-1, k)  # a reshaped contiguous buffer
        scatter_rows(view, np.array([3, 39]), rows[:2])
        np.testing.assert_array_equal(view[[3, 39]], rows[:2].astype(dtype))
