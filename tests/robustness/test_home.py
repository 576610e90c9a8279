"""A missing or read-only home folder (issue 23): ``HOME=/nonexistent/home`` must not make that
whole path (facetex's cache, matplotlib's folders); the commands work without a cache."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from _robust import FACE, bench_run_folder


@pytest.fixture
def env(monkeypatch):
    for name in ("FACETEX_CACHE", "XDG_CACHE_HOME", "XDG_CONFIG_HOME", "MPLCONFIGDIR"):
        monkeypatch.delenv(name, raising=False)
    return monkeypatch


def _detector_works():
    import dlib
    import numpy as np

    from facetex.io import read_image_uint8
    from facetex.landmarks import _frontal_face_detector

    rects = _frontal_face_detector()(np.ascontiguousarray(read_image_uint8(FACE)), 0)
    assert len(rects) == 1 and isinstance(rects[0], dlib.rectangle)


def test_missing_home_makes_nothing(env, tmp_path):
    env.setenv("HOME", str(tmp_path / "nonexistent" / "home"))
    _detector_works()
    assert not (tmp_path / "nonexistent").exists()


@pytest.mark.parametrize("var, value, made", [
    ("HOME", "home", "home/.cache/facetex"),
    ("XDG_CACHE_HOME", "xdg", "xdg/facetex"),
    ("FACETEX_CACHE", "mine", "mine"),
])
def test_cache_made_in_an_existing_folder(env, tmp_path, var, value, made):
    env.setenv("HOME", str(tmp_path / "home"))
    (tmp_path / "home").mkdir()
    env.setenv(var, str(tmp_path / value))
    _detector_works()
    folder = tmp_path / made
    assert len(list(folder.glob("dlib-*-frontal_face_detector.svm"))) == 1
    assert folder.stat().st_mode & 0o777 == 0o700


@pytest.mark.parametrize("var", ["XDG_CACHE_HOME", "FACETEX_CACHE"])
def test_cache_parent_missing(env, tmp_path, var):
    env.setenv("HOME", str(tmp_path / "nonexistent" / "home"))
    env.setenv(var, str(tmp_path / "missing" / "deeper" / "cache"))
    _detector_works()
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_read_only_home(env, readonly_dir):
    env.setenv("HOME", str(readonly_dir))
    _detector_works()
    assert list(readonly_dir.iterdir()) == []


@pytest.mark.parametrize("command", ["landmarks", "report"])
def test_cli_with_a_missing_home(tmp_path, command):
    """Real processes (matplotlib reads HOME when imported): exit 0, no warning, nothing made."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("FACETEX_CACHE", "XDG_CACHE_HOME", "XDG_CONFIG_HOME", "MPLCONFIGDIR")}
    env.update(HOME=str(tmp_path / "nonexistent" / "home"), PYTHONPATH=os.pathsep.join(sys.path))
    if command == "landmarks":
        argv = ["landmarks", str(FACE), "--json"]
    else:
        argv = ["report", str(bench_run_folder(tmp_path / "run")), "-o", str(tmp_path / "r.html")]
    r = subprocess.run([sys.executable, "-m", "facetex", *argv], env=env, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    assert "warning" not in r.stderr.lower() and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "nonexistent").exists()


