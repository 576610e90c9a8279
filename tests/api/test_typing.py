"""Type checkers see the public API (issue 24): the package's stub lists every lazy export, and
mypy on a user script reveals real signatures and flags a wrong ``method=``."""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import facetex

ROOT = Path(facetex.__file__).resolve().parent


def _stub_names() -> set[str]:
    tree = ast.parse((ROOT / "__init__.pyi").read_text())
    names = {a.asname or a.name for node in tree.body if isinstance(node, ast.ImportFrom) for a in node.names}
    return names | {n.target.id for n in tree.body if isinstance(n, ast.AnnAssign)}


def test_the_stub_lists_every_public_name():
    public = set(facetex.__all__)
    assert public == _stub_names() - {"__all__"}, sorted(public ^ (_stub_names() - {"__all__"}))


def test_the_stub_is_shipped_with_the_package():
    import tomllib

    data = tomllib.loads((ROOT.parent / "pyproject.toml").read_text())
    assert "*.pyi" in data["tool"]["setuptools"]["package-data"]["facetex"]


@pytest.mark.skipif(shutil.which("mypy") is None and not any(
    (Path(p) / "mypy").is_dir() for p in sys.path), reason="mypy is not installed (pip install '.[test]')")
def test_mypy_sees_real_types_and_catches_a_wrong_method(tmp_path):
    script = tmp_path / "user.py"
    script.write_text(
        "import numpy as np\nimport facetex\n\n"
        "img = np.zeros((64, 64, 3), np.float32)\n"
        "reveal_type(facetex.transfer)\n"
        "reveal_type(facetex.detect_face)\n"
        "reveal_type(facetex.identity_distance)\n"
        "out = facetex.transfer(img, img, method='neural')\n"
        "ok = facetex.transfer(img, img, method='mrf', preset='preview')\n")
    env = dict(os.environ, MYPYPATH=str(ROOT.parent))  # as an installed (non-editable) package is found
    r = subprocess.run([sys.executable, "-m", "mypy", str(script), "--follow-imports=silent",
                        "--cache-dir", str(tmp_path / "cache"), "--no-error-summary"],
                       capture_output=True, text=True, env=env, timeout=600)
    lines = r.stdout.splitlines()
    revealed = [ln for ln in lines if "Revealed type" in ln]
    assert len(revealed) == 3 and not any('"Any"' in ln for ln in revealed), r.stdout
    assert "method: Literal['facetex'] | Literal['mrf'] | Literal['gatys']" in revealed[0]
    assert "ImageLike" in revealed[1] or "PIL.Image.Image" in revealed[1]
    errors = [ln for ln in lines if ": error:" in ln]
    assert len(errors) == 1 and "user.py:8:" in errors[0] and "'neural'" in errors[0], r.stdout
