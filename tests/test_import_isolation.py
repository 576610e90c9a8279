"""Every facetex module imports on its own, first, in a fresh interpreter (issue 24).

An import circle between modules that import each other at the top fails only when one of them
is imported first: a test run, which imports everything in some order, can miss it.
(``test_import_graph`` reads the imports statically; it does not follow imports of packages such
as ``facetex.io``, whose ``__init__`` imports its private modules.) Here each module is imported
in a process of its own that has loaded no facetex module before: a child forked from an
interpreter that has imported only the third-party libraries (so that each import costs
milliseconds, not torch's seconds), or ``python -c "import facetex.x.y"`` where there is no fork.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "facetex"

#: imported by the parent before forking: the slow third-party imports, none of them facetex
_PRELOAD = ("numpy", "scipy", "scipy.ndimage", "cv2", "PIL.Image", "torch", "av", "skimage", "matplotlib",
            "matplotlib.pyplot", "jsonschema", "tqdm", "dlib")

_DRIVER = r"""
import importlib, os, sys, traceback
for name in sys.argv[2].split(","):
    try:
        importlib.import_module(name)
    except Exception:
        pass
failed = []
for name in sys.argv[1].split(","):
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(r)
        code = 0
        try:
            assert not [m for m in sys.modules if m == "facetex" or m.startswith("facetex.")]
            importlib.import_module(name)
        except BaseException:
            os.write(w, traceback.format_exc().encode())
            code = 1
        os._exit(code)
    os.close(w)
    chunks = []
    while True:
        b = os.read(r, 65536)
        if not b:
            break
        chunks.append(b)
    os.close(r)
    _, status = os.waitpid(pid, 0)
    if status != 0:
        failed.append(name + ":\n" + b"".join(chunks).decode(errors="replace"))
print("\n".join(failed))
sys.exit(1 if failed else 0)
"""


def _modules() -> list[str]:
    out = []
    for p in sorted(ROOT.rglob("*.py")):
        parts = list(p.relative_to(ROOT.parent).with_suffix("").parts)
        if parts[-1] == "__main__":  # importing it runs the command line
            continue
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out.append(".".join(parts))
    return out


def test_modules_are_found():
    mods = _modules()
    assert "facetex" in mods and "facetex.io" in mods and "facetex.io._read" in mods and len(mods) > 100


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT.parent), *filter(None, [env.get("PYTHONPATH")])])
    return env


def test_every_module_imports_first_in_a_fresh_interpreter():
    mods = _modules()
    if hasattr(os, "fork"):
        run = subprocess.run([sys.executable, "-c", _DRIVER, ",".join(mods), ",".join(_PRELOAD)],
                             capture_output=True, text=True, env=_env(), timeout=600)
        assert run.returncode == 0, f"modules that fail when imported first:\n{run.stdout}{run.stderr[-3000:]}"
        return
    failed = []
    for module in mods:
        run = subprocess.run([sys.executable, "-c", f"import {module}"], capture_output=True, text=True,
                             env=_env(), timeout=300)
        if run.returncode:
            failed.append(f"{module}:\n{run.stderr[-3000:]}")
    assert not failed, "modules that fail when imported first:\n" + "\n".join(failed)
