"""Harder copies of the driver clips for ``facetex bench puppet --stress``: the clips a new user
brings are not GRID's frontal, evenly lit studio faces.

Each perturbation makes one copy, of the clips in turn (the first clip mirrored and side-lit, the
second rotated with its face shrunk, the third dimmed with sensor noise, the fourth with a dark
skin; fewer clips are reused),
written once to ``OUT/stress/`` and reused by later runs in the same folder:

* ``mirror_sidelit``: flipped left-right (a face seen from its other side) and lit from one side
  (a gain falling linearly from 1.25 to 0.45 across the frame);
* ``rotated_small``: rolled 14 degrees and shrunk to 0.7 of its size about the frame's centre
  (reflected borders): a tilted head further from the camera;
* ``dim_noisy``: 0.45 x the exposure plus a 8/255 black level and Gaussian noise of 6/255 (seeded):
  a dim room on a webcam. The puppet's lips and teeth are then a few CIELAB units apart.
* ``dark_skin``: the skin-coloured pixels (a YCrCb box, Cr 138-200 and Cb 55-125, opened and
  feathered, not facetex's own skin model) darkened in linear light by (0.24, 0.19, 0.15) to a brown
  of median luma ~0.28: a dark-skinned speaker (the shared clips' speakers are light-skinned). The
  box holds the lips and some of the teeth too, which darken with the skin.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["STRESS", "stress_sources", "stress_frame", "stress_clips"]

#: the perturbations, in the order they take the clips
STRESS = ("mirror_sidelit", "rotated_small", "dim_noisy", "dark_skin")

#: dark_skin's linear-light gains (R, G, B) of the skin-coloured pixels
DARK_SKIN_GAIN = (0.24, 0.19, 0.15)


def stress_frame(frame: np.ndarray, kind: str, rng: np.random.Generator) -> np.ndarray:
    """One float RGB frame (H, W, 3) in [0, 1] perturbed by ``kind`` (:data:`STRESS`)."""
    import cv2

    f = np.asarray(frame, np.float32)
    h, w = f.shape[:2]
    if kind == "mirror_sidelit":
        out = f[:, ::-1] * np.linspace(1.25, 0.45, w, dtype=np.float32)[None, :, None]
    elif kind == "rotated_small":
        m = cv2.getRotationMatrix2D((w / 2, h / 2), 14.0, 0.7)
        out = cv2.warpAffine(f, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    elif kind == "dim_noisy":
        out = f * 0.45 + 8 / 255 + rng.normal(0.0, 6 / 255, f.shape).astype(np.float32)
    elif kind == "dark_skin":
        from ..puppet.lighting import linear_to_srgb, srgb_to_linear

        u8 = (np.clip(f, 0, 1) * 255 + 0.5).astype(np.uint8)
        ycc = cv2.cvtColor(u8, cv2.COLOR_RGB2YCrCb)
        cr, cb = ycc[..., 1].astype(np.int16), ycc[..., 2].astype(np.int16)
        m = ((cr > 138) & (cr < 200) & (cb > 55) & (cb < 125)).astype(np.float32)
        m = cv2.GaussianBlur(cv2.morphologyEx(m, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)), (0, 0), 2.0)[..., None]
        lin = srgb_to_linear(np.clip(f, 0, 1))
        out = linear_to_srgb(lin * (1.0 - m + m * np.float32(DARK_SKIN_GAIN)))
    else:
        raise ValueError(f"unknown perturbation {kind!r}; one of {STRESS}")
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def stress_sources(files) -> list[tuple[Path, str]]:
    """(clip, perturbation) of each copy: :data:`STRESS` in order, taking ``files`` in turn."""
    files = [Path(f) for f in files]
    return [(files[k % len(files)], kind) for k, kind in enumerate(STRESS)]


def stress_clips(files, out, *, seed: int = 0, max_frames: int | None = None) -> list[Path]:
    """The perturbed copies (:data:`STRESS`, one each, of ``files`` in turn) in ``out/stress/``:
    ``<clip>_<perturbation>.mp4``, written when missing (atomically). Returns their paths."""
    from ..io import iter_video_frames, video_info, write_video

    folder = Path(out) / "stress"
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k, (src, kind) in enumerate(stress_sources(files)):
        dst = folder / f"{src.stem}_{kind}.mp4"
        if not dst.exists():
            rng = np.random.default_rng([seed, k])
            frames = (stress_frame(f, kind, rng) for f in iter_video_frames(src, max_frames=max_frames))
            write_video(dst, frames, video_info(src)["fps"] or 25.0, overwrite=False)
        paths.append(dst)
    return paths
