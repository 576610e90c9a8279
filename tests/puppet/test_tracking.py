"""Driver tracking in a child process (facetex.puppet._tracking)."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from facetex.errors import BadInputError, FacetexError, NoFaceError
from facetex.io import write_video
from facetex.puppet._tracking import DriverTracking
from facetex.puppet.driver import DriverParams, track_driver


@pytest.fixture(scope="module")
def driver(tmp_path_factory):
    from test_puppet import morph_frames  # same folder (rootdir-less import)

    path = tmp_path_factory.mktemp("drv") / "drv.mp4"
    write_video(path, morph_frames(n_morph=4, n_blank=1, n_hold=1), fps=10)
    return path


def test_child_process_tracks_like_the_calling_thread(driver):
    ticks = []
    tr = DriverTracking(driver, frontal_images=False).result(lambda **k: ticks.append(k))
    ref = track_driver(driver, frontal_images=False)
    assert [t["stage"] for t in ticks] == ["track"] * ref.n_frames
    assert ticks[-1]["lost"] == 1
    np.testing.assert_array_equal(tr.found, ref.found)
    np.testing.assert_array_equal(tr.points68, ref.points68)
    np.testing.assert_array_equal(tr.mesh, ref.mesh)
    np.testing.assert_array_equal(tr.frontal_points68, ref.frontal_points68)
    assert (tr.frame_size, tr.fps, tr.lost_reason) == (ref.frame_size, ref.fps, ref.lost_reason)


def test_child_imports_this_facetex_not_the_working_folders(driver, tmp_path, monkeypatch):
    fake = tmp_path / "facetex"  # another checkout's package in the working folder
    fake.mkdir()
    (fake / "__init__.py").write_text("raise ImportError('the wrong facetex')\n")
    monkeypatch.chdir(tmp_path)
    tr = DriverTracking(driver, frontal_images=False).result()
    assert tr.n_frames == track_driver(driver, frontal_images=False).n_frames


def test_child_process_errors_reach_the_caller_with_the_file(tmp_path):
    p = tmp_path / "noface.mp4"
    write_video(p, [np.full((64, 64, 3), 0.5, np.float32)] * 2, fps=5)
    with pytest.raises(NoFaceError) as e:
        DriverTracking(p).result()
    assert e.value.path == str(p) and "no usable face" in str(e.value)


def test_a_killed_child_is_reported(driver):
    job = DriverTracking(driver)
    job._proc.kill()
    with pytest.raises(FacetexError, match="tracking process stopped"):
        job.result()


def test_cancel_stops_the_child(driver):
    job = DriverTracking(driver)
    proc = job._proc
    job.cancel()
    assert proc.poll() is not None
    job.cancel()  # twice is harmless


def test_a_dropped_tracking_stops_its_child(driver):
    import gc

    job = DriverTracking(driver)
    proc = job._proc
    del job
    gc.collect()
    assert proc.wait(timeout=10) is not None


def test_errors_pickle_with_their_path():
    e = pickle.loads(pickle.dumps(NoFaceError("no face", path="/x/y.mp4")))
    assert type(e) is NoFaceError and e.path == "/x/y.mp4" and str(e) == "/x/y.mp4: no face"


def test_puppetry_refuses_a_tracking_started_otherwise(driver, monkeypatch):
    import facetex.puppet.puppetry as puppet
    from facetex.puppet.puppetry import prepare_puppetry

    monkeypatch.setattr(puppet, "_persona_size", lambda persona: (192, 240))  # only the size is read first
    job = DriverTracking(driver, process=False, max_frames=None, params=DriverParams(size=(10, 10)),
                         frontal_images=False)
    with pytest.raises(BadInputError, match="tracking was started"):
        prepare_puppetry(driver, "unused.persona", tracking=job)
    with pytest.raises(BadInputError, match="unknown tracking"):
        prepare_puppetry(driver, "unused.persona", tracking="fork")

