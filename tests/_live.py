"""Helpers of the live tests (tests/live): driver frames from the bundled samples. A module of its
own, not the live conftest: ``from conftest import ...`` gets whichever conftest pytest imported
last (tests/studio's when both folders are named on the command line)."""

from __future__ import annotations

import cv2
import numpy as np

from facetex._resources import sample_path
from facetex.io import read_image, to_uint8


def driver_frames(n_morph: int = 8, n_blank: int = 2, n_hold: int = 3, side: int = 192) -> list[np.ndarray]:
    """uint8 frames: frl_004 neutral -> smiling (cross-fade of the aligned pair), ``n_blank`` grey
    frames (face lost), ``n_hold`` smiling frames."""
    a = cv2.resize(read_image(sample_path("frl_004_neutral.jpg")), (side, side), interpolation=cv2.INTER_AREA)
    b = cv2.resize(read_image(sample_path("frl_004_smiling.jpg")), (side, side), interpolation=cv2.INTER_AREA)
    frames = [to_uint8((1 - t) * a + t * b) for t in np.linspace(0, 1, n_morph)]
    frames += [np.full((side, side, 3), 115, np.uint8)] * n_blank + [to_uint8(b)] * n_hold
    return frames
