"""build_persona from a plain script without ``if __name__ == "__main__":`` (issue 24): the
workers must not re-run the script (multiprocessing's forkserver imports the parent's main
script in every child), and the build must succeed."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from _photos import write_jittered_copies

import facetex

ROOT = Path(facetex.__file__).resolve().parents[1]


def test_build_persona_runs_from_a_plain_script(tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    write_jittered_copies(photos, 4, np.random.default_rng(0))
    script = tmp_path / "plain.py"
    script.write_text("import facetex\n"
                      "print('SCRIPT-RAN', flush=True)\n"
                      f"p = facetex.build_persona({str(photos)!r}, jobs=2, min_photos=6)\n"
                      "print('BUILT', len(p), flush=True)\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=env, timeout=600,
                       cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.count("SCRIPT-RAN") == 1  # not once more per worker
    assert "BUILT 8" in r.stdout
