"""Harder copies of the driver clips (facetex.bench._stress_clips, ``facetex bench puppet --stress``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from facetex.bench._stress_clips import STRESS, stress_clips, stress_frame
from facetex.io import iter_video_frames, write_video


def test_mirror_sidelit_flips_and_lights_from_one_side():
    f = np.tile(np.linspace(0.2, 0.6, 40, dtype=np.float32)[None, :, None], (30, 1, 3))
    out = stress_frame(f, "mirror_sidelit", np.random.default_rng(0))
    np.testing.assert_allclose(out[:, 0], f[:, -1] * 1.25, atol=1e-6)  # the right edge, lit
    np.testing.assert_allclose(out[:, -1], f[:, 0] * 0.45, atol=1e-6)  # the left edge, in shadow


def test_rotated_small_rolls_and_shrinks_about_the_centre():
    f = np.zeros((101, 121, 3), np.float32)
    f[48:53, 98:103] = 1.0  # a dot 40 px right of the centre (60, 50)
    out = stress_frame(f, "rotated_small", np.random.default_rng(0))[..., 0]
    out[:, 96:] = 0  # the borders reflect the frame: its dot's mirror image
    yy, xx = np.mgrid[0:101, 0:121]
    y, x = (out * yy).sum() / out.sum(), (out * xx).sum() / out.sum()
    a = math.radians(14.0)  # OpenCV: counter-clockwise on screen (y down): the dot moves up
    assert abs(x - (60 + 28 * math.cos(a))) <= 1 and abs(y - (50 - 28 * math.sin(a))) <= 1


def test_dim_noisy_is_dim_noisy_and_seeded():
    f = np.full((200, 200, 3), 0.8, np.float32)
    a = stress_frame(f, "dim_noisy", np.random.default_rng(3))
    assert abs(a.mean() - (0.8 * 0.45 + 8 / 255)) < 2e-3 and abs(a.std() - 6 / 255) < 2e-3
    np.testing.assert_array_equal(a, stress_frame(f, "dim_noisy", np.random.default_rng(3)))
    with pytest.raises(ValueError, match="unknown perturbation"):
        stress_frame(f, "blurry", np.random.default_rng(0))


def test_dark_skin_darkens_skin_coloured_pixels_only():
    """A light-skin patch on a blue background: the patch's middle darkened in linear light by
    DARK_SKIN_GAIN per channel (sRGB 0.85, 0.65, 0.55 -> linear 0.692, 0.380, 0.263 -> x (0.24, 0.19,
    0.15) = 0.1661, 0.0722, 0.0395 -> sRGB 0.444, 0.298, 0.219), the background untouched."""
    from facetex.bench._stress_clips import DARK_SKIN_GAIN

    f = np.tile(np.float32([0.2, 0.55, 0.8]), (60, 80, 1))
    f[15:45, 20:60] = [0.85, 0.65, 0.55]
    out = stress_frame(f, "dark_skin", np.random.default_rng(0))
    assert DARK_SKIN_GAIN == (0.24, 0.19, 0.15)
    np.testing.assert_allclose(out[30, 40], [0.444, 0.298, 0.219], atol=2e-3)
    np.testing.assert_allclose(out[:5], f[:5], atol=1e-6)
    np.testing.assert_allclose(out[:, :8], f[:, :8], atol=1e-6)


def test_stress_clips_one_copy_each_of_the_clips_in_turn(tmp_path):
    src = []
    for k, name in enumerate(("a", "b")):
        frames = [np.full((48, 64, 3), 0.3 + 0.1 * k + 0.05 * t, np.float32) for t in range(4)]
        src.append(write_video(tmp_path / f"{name}.mp4", frames, fps=25))
    paths = stress_clips(src, tmp_path / "out")
    assert [p.name for p in paths] == ["a_mirror_sidelit.mp4", "b_rotated_small.mp4", "a_dim_noisy.mp4",
                                       "b_dark_skin.mp4"]
    assert len(STRESS) == 4
    dim = list(iter_video_frames(paths[2]))
    assert len(dim) == 4 and abs(float(dim[0].mean()) - (0.3 * 0.45 + 8 / 255)) < 0.03
    # written once: a second call reuses the copies
    stamp = [p.stat().st_mtime_ns for p in paths]
    assert [p.stat().st_mtime_ns for p in stress_clips(src, tmp_path / "out")] == stamp
