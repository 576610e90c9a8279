"""No module of the package is over ~600 lines (issue 24): split by what the code does before
one grows past it."""

from __future__ import annotations

from pathlib import Path

import facetex

LIMIT = 600


def test_no_module_over_600_lines():
    root = Path(facetex.__file__).parent
    sizes = {p.relative_to(root).as_posix(): len(p.read_text(encoding="utf-8").splitlines())
             for p in root.rglob("*.py")}
    assert len(sizes) > 50  # the package itself, not an empty folder
    over = {k: v for k, v in sizes.items() if v > LIMIT}
    assert not over, f"modules over {LIMIT} lines: {over}"
