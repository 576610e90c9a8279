"""Worker processes (issue 23): a long TMPDIR (the forkserver's AF_UNIX socket path), and
workers that die with a SIGKILLed parent instead of running on."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest

from _robust import assert_one_error, run_cli, snapshot


def _long_tmpdir(tmp_path):
    d = tmp_path / ("t" * 60) / ("m" * 60)  # with pymp-*/listener-*: over the 107 bytes of a socket path
    d.mkdir(parents=True)
    return d


def _env(**extra):
    return {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path), **extra}


def test_persona_build_jobs_2_with_a_long_tmpdir(tmp_path, photo_dir):
    tmp = _long_tmpdir(tmp_path)
    out = tmp_path / "p.persona"
    r = subprocess.run([sys.executable, "-m", "facetex", "persona", "build", str(photo_dir), "-o", str(out),
                        "--jobs", "2", "--min-photos", "3", "--allow-mixed", "-q"],
                       env=_env(TMPDIR=str(tmp)), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and out.is_file()
    assert list(tmp.iterdir()) == []  # multiprocessing's folder went elsewhere, and is gone


def test_no_short_temp_folder_is_one_line(capsys, tmp_path, photo_dir, outdir, monkeypatch):
    """No writable short folder either: one line naming TMPDIR and --jobs, before any work."""
    import multiprocessing.util
    import tempfile

    import facetex._parallel as par

    tmp = _long_tmpdir(tmp_path)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    monkeypatch.setattr(par, "_SHORT_TEMP_FOLDERS", ())
    monkeypatch.setattr(multiprocessing.util, "get_temp_dir", lambda: os.path.join(tempfile.gettempdir(), "pymp-x"))
    run = run_cli(capsys, "persona", "build", photo_dir, "-o", outdir / "p.persona", "--jobs", "2", "--min-photos",
                  "3", "--allow-mixed")
    assert_one_error(run, names=[tmp / "pymp-x"], cause=r"too long a path .*socket.*TMPDIR.*--jobs 1")
    assert snapshot(outdir) == {}


@pytest.fixture(scope="module")
def many_photos(tmp_path_factory, photo_dir):
    """24 photos (the bundled faces four times): a build long enough to kill in the middle."""
    d = tmp_path_factory.mktemp("many")
    for k in range(4):
        for p in sorted(photo_dir.iterdir()):
            shutil.copy(p, d / f"{k}_{p.name}")
    return d
