"""numpydoc's own validation of every public export (issue 24): every parameter documented, in
order, every function's Returns described. Style-only checks are left out (listed below, as
scikit-image's and pandas' numpydoc configurations do)."""

from __future__ import annotations

import inspect

import pytest

import facetex

numpydoc_validate = pytest.importorskip("numpydoc.validate", reason="numpydoc is in the test extra")

#: style checks not enforced: See Also, Examples (the API functions have them: test_api),
#: extended summary, blank lines round the text, summary wording and length, a description's
#: capital letter and final period
STYLE_ONLY = {"SA01", "EX01", "ES01", "GL01", "GL02", "SS05", "SS06", "PR08", "PR09", "RT05"}

EXPORTS = [n for n in facetex.__all__ if n != "__version__" and not inspect.ismodule(getattr(facetex, n))]


@pytest.mark.parametrize("name", EXPORTS)
def test_numpydoc_validation_passes(name):
    res = numpydoc_validate.validate(f"facetex.{name}")
    errors = [f"{code}: {msg}" for code, msg in res["errors"] if code not in STYLE_ONLY]
    assert not errors, f"facetex.{name}: " + "; ".join(errors)


def test_every_export_is_checked():
    assert len(EXPORTS) >= 30 and {"detect_face", "transfer_metrics", "read_image", "BadImageError"} <= set(EXPORTS)
