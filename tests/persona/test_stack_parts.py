"""The texture stacks' memory: one small-page map, made at once where huge pages are on request."""

import numpy as np
import pytest

from facetex.persona import _stack_parts as sp


@pytest.mark.parametrize("always", [False, True])
def test_small_page_arrays_are_zeroed_separate_and_aligned(monkeypatch, always):
    monkeypatch.setattr(sp, "_huge_pages_always", lambda: always)
    shapes = [(3, 5), (7, 11), (1, 1)]
    arrays = sp._small_page_arrays(shapes)
    assert [a.shape for a in arrays] == shapes and all(a.dtype == np.float32 for a in arrays)
    assert all(not a.any() for a in arrays)
    assert all(a.ctypes.data % 64 == 0 for a in arrays)
    for k, a in enumerate(arrays):
        a[...] = k + 1
    assert [float(a.min()) for a in arrays] == [1.0, 2.0, 3.0]  # no overlap
    assert [float(a.max()) for a in arrays] == [1.0, 2.0, 3.0]


def test_huge_page_mode_is_read_from_the_kernel(monkeypatch, tmp_path):
    import builtins

    real_open = builtins.open
    for text, want in [("always [madvise] never\n", False), ("[always] madvise never\n", True)]:
        f = tmp_path / "enabled"
        f.write_text(text)
        monkeypatch.setattr(builtins, "open", lambda p, *a, _f=f, **k: real_open(
            _f if str(p).endswith("transparent_hugepage/enabled") else p, *a, **k))
        assert sp._huge_pages_always() is want
    monkeypatch.setattr(builtins, "open", lambda *a, **k: (_ for _ in ()).throw(OSError("no sysfs")))
    assert sp._huge_pages_always() is False
