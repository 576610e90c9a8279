"""Small synthetic photo collections and tiny personas for persona tests (shared by several test
folders)."""

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


def build_tiny_persona(path: Path, *, photos: Path | None = None, copies: int = 4, seed: int = 0,
                       size: tuple[int, int] = (96, 120), min_photos: int = 6) -> Path:
    """A tiny persona saved as ``path``: built (one job) from ``photos``, by default ``copies``
    jittered copies (:func:`write_jittered_copies`, ``np.random.default_rng(seed)``) of each frl_004
    portrait written in a new folder ``<path stem>_photos`` next to ``path``; the canonical frame
    ``size`` (W, H) is half the default one, fast to build, load and render. Returns ``path``."""
    from facetex.persona import PersonaParams, build_persona

    path = Path(path)
    if photos is None:
        photos = path.parent / f"{path.stem}_photos"
        photos.mkdir()
        write_jittered_copies(photos, copies, np.random.default_rng(seed))
    build_persona(photos, jobs=1, params=PersonaParams(min_photos=min_photos, size=size)).save(path)
    return path


def draw_glasses(img: np.ndarray, points68: np.ndarray, *, arms: bool = True, colour: int = 30) -> np.ndarray:
    """uint8 ``img`` with a pair of glasses drawn at its iBUG landmarks: two dark rims round the eyes,
    the bridge and (``arms``) the arms to the face's sides, lines 0.04 of the eye distance thick
    (at least 2 px)."""
    out = img.copy()
    p = np.asarray(points68, np.float64)
    iod = float(np.linalg.norm(p[36:42].mean(0) - p[42:48].mean(0)))
    t = max(2, int(round(0.04 * iod)))
    c3 = (colour,) * 3
    for eye, jaw in ((p[36:42], p[0]), (p[42:48], p[16])):
        c = eye.mean(0)
        cv2.ellipse(out, tuple(int(v) for v in c), (int(0.42 * iod), int(0.28 * iod)), 0, 0, 360, c3, t)
        if arms:
            x = c[0] + np.sign(jaw[0] - c[0]) * 0.42 * iod
            cv2.line(out, (int(x), int(c[1])), (int(jaw[0]), int(c[1] - 0.05 * iod)), c3, t)
    y = int(round((p[39, 1] + p[42, 1]) / 2 - 0.1 * iod))
    cv2.line(out, (int(p[39, 0]), y), (int(p[42, 0]), y), c3, t)
    return out


def simple_face68() -> np.ndarray:
    """(68, 2) iBUG-shaped points of a frontal face in a 256 px frame: jaw, brows at y ~ 80, eyes at
    y 100, nose, lips at y ~ 170."""
    p = np.zeros((68, 2))
    t = np.linspace(np.pi, 0, 17)
    p[0:17] = np.c_[128 + 90 * np.cos(t), 100 + 110 * np.sin(t)]
    p[17:22] = np.c_[np.linspace(60, 115, 5), 80 - 8 * np.sin(np.linspace(0, np.pi, 5))]
    p[22:27] = np.c_[np.linspace(141, 196, 5), 80 - 8 * np.sin(np.linspace(0, np.pi, 5))]
    p[27:31] = np.c_[np.full(4, 128.0), np.linspace(100, 140, 4)]
    p[31:36] = np.c_[np.linspace(114, 142, 5), np.full(5, 145.0)]
    for k, cx in ((36, 88.0), (42, 168.0)):
        a = np.linspace(np.pi, -np.pi, 6, endpoint=False)
        p[k:k + 6] = np.c_[cx + 16 * np.cos(a), 100 - 6 * np.sin(a)]
    a = np.linspace(np.pi, -np.pi, 12, endpoint=False)
    p[48:60] = np.c_[128 + 30 * np.cos(a), 170 - 10 * np.sin(a)]
    a = np.linspace(np.pi, -np.pi, 8, endpoint=False)
    p[60:68] = np.c_[128 + 20 * np.cos(a), 170 - 3 * np.sin(a)]
    return p
