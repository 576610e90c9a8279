"""Small synthetic photo collections for persona tests (shared by several test folders)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from facetex._resources import sample_path
from facetex.io import read_image, write_image


def write_jittered_copies(folder: Path, copies: int, rng: np.random.Generator) -> None:
    """``copies`` jittered copies (rotation ±6°, scale 0.92–1.05, gain 0.85–1.1) of the bundled
    frl_004 neutral and smiling portraits, written as ``frl_004_<expr>_<k>.png`` in ``folder``."""
    for name in ("frl_004_neutral", "frl_004_smiling"):
        img = read_image(sample_path(f"{name}.jpg"))
        h, w = img.shape[:2]
        for k in range(copies):
            m = cv2.getRotationMatrix2D((w / 2, h / 2), rng.uniform(-6, 6), rng.uniform(0.92, 1.05))
            j = cv2.warpAffine(img, m, (w, h), borderMode=cv2.BORDER_REPLICATE)
            write_image(Path(folder) / f"{name}_{k}.png", np.clip(j * rng.uniform(0.85, 1.1), 0, 1))
