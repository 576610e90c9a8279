"""LiveSession end to end on a tiny persona and a short synthetic driver (frames given one at a time)."""

from __future__ import annotations

import numpy as np
import pytest

from _live import driver_frames
from facetex.errors import BadInputError
from facetex.live import LiveParams, LiveSession

N_MORPH, N_BLANK, N_HOLD = 8, 2, 3
WARMUP = 3


def _run(persona, tracking: str, mode: str = "composite", render: str = "thread"):
    live = LiveParams(warmup=WARMUP, tracking=tracking, render=render)
    with LiveSession(persona, size=128, mode=mode, live=live, background=False) as s:
        # stream times given: the filters' time steps (else the calls' own timing) are the same in every run
        outs = [s.process(f, t=i / 25) for i, f in enumerate(driver_frames(N_MORPH, N_BLANK, N_HOLD))]
        return outs, s.stats()


@pytest.fixture(scope="module")
def thread_run(live_persona):
    return _run(live_persona, "thread")


def test_warmup_then_puppet_frames(thread_run):
    outs, st = thread_run
    # the first WARMUP - 1 frames make the reference (no output); the WARMUP-th completes it and comes out
    assert all(o is None for o in outs[:WARMUP - 1])
    assert all(o is not None for o in outs[WARMUP - 1:])
    for o in outs[WARMUP - 1:]:
        assert o.dtype == np.uint8 and o.shape == (128, 128, 3)
    assert st["warmup_frames"] == WARMUP - 1
    assert st["puppet_frames"] == N_MORPH + N_HOLD - (WARMUP - 1)
    assert st["lost_frames"] == N_BLANK
    assert st["frames_out"] == st["puppet_frames"] + st["lost_frames"]
    assert st["dropped"] == 0 and st["latency_ms_p50"] > 0 and st["latency_ms_p95"] >= st["latency_ms_p50"]
    assert st["first_puppet_s"] > 0 and st["detections"] >= 2  # detected at the start and after the gap


def test_lost_frames_show_the_driver_and_puppet_differs(thread_run):
    import cv2

    outs, _ = thread_run
    frames = driver_frames(N_MORPH, N_BLANK, N_HOLD)
    for i in range(N_MORPH, N_MORPH + N_BLANK):  # grey frames: the driver's own frame
        np.testing.assert_array_equal(outs[i], cv2.resize(frames[i], (128, 128), interpolation=cv2.INTER_AREA))
    # puppet frames: the face region changed, the corners (background) did not
    i = N_MORPH - 1
    drv = cv2.resize(frames[i], (128, 128), interpolation=cv2.INTER_AREA).astype(float)
    diff = np.abs(outs[i].astype(float) - drv).mean(axis=2)
    assert diff[40:90, 40:90].mean() > 3 * max(diff[:10, :10].mean(), 0.5)


def test_child_processes_give_the_same_frames(live_persona, thread_run):
    """Tracking and rendering in child processes (the default) make the frames made in this one."""
    outs, st = _run(live_persona, "process", render="process")
    for a, b in zip(outs, thread_run[0]):
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a, b)


def test_face_mode(live_persona):
    outs, st = _run(live_persona, "thread", mode="face")
    grey = outs[N_MORPH]  # lost: a plain panel
    assert (grey == grey[0, 0]).all()
    assert st["puppet_frames"] > 0


def test_bad_frames_and_settings(live_persona):
    with pytest.raises(BadInputError, match="uint8"):
        with LiveSession(live_persona, live=LiveParams(tracking="thread"), background=False) as s:
            s.process(np.zeros((64, 64, 3), np.float32))
    with pytest.raises(BadInputError, match="mode"):
        LiveSession(live_persona, mode="side")
    with pytest.raises(BadInputError, match="warm-up"):
        LiveParams(warmup=0).check()


def test_missing_persona_raises_at_once(tmp_path):
    with pytest.raises(FileNotFoundError):
        LiveSession(tmp_path / "none.persona", live=LiveParams(tracking="thread"))


def test_stored_static_texture_is_the_uniform_blend(live_persona):
    """The texture the first puppet frames use while the stacks load: the file's static pyramid sums."""
    from facetex.live._loading import stored_static_texture
    from facetex.persona import load_persona
    from facetex.persona.texture import blend_weights
    from facetex.puppet import PuppetParams

    p = load_persona(live_persona)
    tp = PuppetParams().texture_params()
    static = stored_static_texture(p, tp)
    assert static is not None and static.shape == (120, 96, 3) and static.dtype == np.float32
    assert 0 <= static.min() and static.max() <= 1
    uniform = blend_weights(p, np.ones((1, 3, len(p))), params=tp)[0]  # every photo the same weight
    assert np.abs(static - uniform).mean() < 0.02
    p.texture_stacks = None  # a persona without stored stacks: no static start
    assert stored_static_texture(p, tp) is None


def test_the_drivers_glasses_stay_in_front_of_the_live_puppet(live_persona):
    """Rims drawn on the driver's frames (moving with its landmarks): found over the warm-up, kept
    in front of the puppet."""
    from _photos import draw_glasses
    from facetex.geometry.glasses import rims_present
    from facetex.landmarks import detect_face

    side = 320  # the eyes ~44 px apart: at 26 px dlib's 1 px jitter smeared drawn 2 px rims
    frames = driver_frames(N_MORPH, 0, N_HOLD, side=side)
    points = [detect_face(f).points68 for f in frames]
    worn = [draw_glasses(f, p, colour=40) for f, p in zip(frames, points)]  # fixed to the head
    live = LiveParams(warmup=WARMUP, tracking="thread", render="thread")
    with LiveSession(live_persona, size=side, mode="composite", live=live, background=False) as s:
        outs = [s.process(f, t=i / 25) for i, f in enumerate(worn)]
        assert rims_present(s.puppeteer.track.rims) and s.puppeteer.glasses
    # the lower rims below the eyes (not the eyes, nose or brows, which are the puppet's)
    i, p = N_MORPH - 1, points[N_MORPH - 1]
    iod = float(np.linalg.norm(p[36:42].mean(0) - p[42:48].mean(0)))
    drawn = np.abs(worn[i].astype(int) - frames[i].astype(int)).sum(-1) > 60
    yy, xx = np.mgrid[:side, :side]
    low = drawn & (yy > p[36:48, 1].max() + 0.15 * iod) & (np.abs(xx - p[27, 0]) > 0.3 * iod)
    assert low.sum() > 40
    err = np.abs(outs[i].astype(int) - worn[i].astype(int)).sum(-1)
    assert np.median(err[low]) < 40
