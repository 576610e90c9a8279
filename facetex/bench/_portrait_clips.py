"""High-resolution drivers for ``facetex bench puppet --portraits N``: still pairs of studio portraits.

GRID's clips are 360 x 288 with ~100 px faces, and most of their speakers are light-skinned men:
faults a 1000 px driver shows at once (soft lip and skin edges next to its pores, dark bands a few
pixels wide, a dark persona's lids on a pale face) do not move their numbers. A portrait folder of
``NNN_neutral.jpg`` / ``NNN_smiling.jpg`` pairs of the same person (the shared data's
``frl-london``: 1000 px, faces 350-450 px wide) gives N clips, each ``HOLD`` frames of the neutral
portrait then ``HOLD`` of the smiling one (a cut: the mouth opens from one frame to the next),
written once to ``OUT/portraits/portrait_<NNN>.mp4`` at 25 fps.

Only pairs whose smile opens the mouth drive the bench (the neutral mouth closed, the smile's
opening larger by :data:`SMILE_OPENING`, as the bench reads them): on a closed-lip smile the
opening changes by the landmarks' noise and the mouth's slope and r measure that noise (a bearded
closed mouth read 0.14 open; 28 of the shared set's 60 pairs open). Among them the N people are
chosen to span skin lightness: each neutral portrait's cheek lightness (median CIELAB L* on
:func:`~facetex.bench.puppet_measures.cheek_mask` at the bench's landmarks) is measured, and the
portraits nearest to N evenly spaced lightness values from the darkest to the palest are taken
(spaced in value, not in rank: the shared set's people are mostly pale, its few dark-skinned ones
would otherwise get one clip; N = 6 there gives three women and three men, two of them dark-skinned,
one with a moustache, one with a goatee). Portraits with no face found are left out.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import BadInputError

__all__ = ["HOLD", "portrait_pairs", "portrait_stats", "opens_with_smile", "choose_portraits", "portrait_clips"]

#: frames of each expression in a portrait clip (0.6 s at 25 fps)
HOLD = 15
FPS = 25.0
#: a portrait pair drives the bench when its neutral mouth reads at most this open and its smile at
#: least SMILE_OPENING more (mouth openings, :func:`~facetex.puppet.driver.mouth_opening`)
CLOSED_OPENING = 0.03
SMILE_OPENING = 0.05


def portrait_pairs(folder) -> dict[str, tuple[Path, Path]]:
    """{id: (neutral, smiling)} of the ``<id>_neutral`` / ``<id>_smiling`` portraits in ``folder``
    (:func:`~facetex.bench._common.list_portraits`, as ``bench transfer`` reads the same folder)."""
    from ._common import list_portraits

    neutral, smiling = (list_portraits(folder, tag=t) for t in ("neutral", "smiling"))
    pairs = {k: (v, smiling[k]) for k, v in neutral.items() if k in smiling}
    if not pairs:
        raise BadInputError("no portrait pairs (NNN_neutral.jpg and NNN_smiling.jpg) in the folder", path=folder)
    return pairs


def portrait_stats(neutral, smiling) -> dict:
    """{"lightness": median CIELAB L* (0..100) of the neutral portrait's cheek patches, "neutral_open",
    "smiling_open": the mouth openings the bench reads (:func:`~facetex.puppet.driver.mouth_opening`)};
    NaN where no face is found. Images: paths or float RGB arrays."""
    from ..io import read_image
    from ..puppet.driver import mouth_opening
    from ._puppet_clip import _frame_measures
    from .puppet_measures import _lab, cheek_mask

    res = {"lightness": float("nan"), "neutral_open": float("nan"), "smiling_open": float("nan")}
    for key, image in (("neutral_open", neutral), ("smiling_open", smiling)):
        img = read_image(image) if not isinstance(image, np.ndarray) else np.asarray(image, np.float32)
        p, _ = _frame_measures(img, descriptor=False)  # read as the bench reads a frame
        if p is None:
            continue
        res[key] = float(mouth_opening(p))
        if key == "neutral_open":
            m = cheek_mask(p, img.shape[:2])
            res["lightness"] = float(np.median(_lab(img[m][None])[0, :, 0])) if m.any() else float("nan")
    return res


def opens_with_smile(stats: dict) -> bool:
    """Whether a pair's mouth is closed when neutral (opening <= :data:`CLOSED_OPENING`) and open in
    the smile (by >= :data:`SMILE_OPENING` more): a closed-lip smile's opening changes by dlib's noise,
    and a slope fitted to it measures that noise."""
    n, s = stats.get("neutral_open", np.nan), stats.get("smiling_open", np.nan)
    return bool(np.isfinite(n) and np.isfinite(s) and n <= CLOSED_OPENING and s - n >= SMILE_OPENING)


def choose_portraits(lightness: dict[str, float], n: int) -> list[str]:
    """The ids of ``n`` portraits whose ``lightness`` is nearest to ``n`` evenly spaced values from the
    darkest to the palest (each taken once; darkest first; NaN left out)."""
    ids = sorted((k for k, v in lightness.items() if np.isfinite(v)), key=lambda k: (lightness[k], k))
    if n >= len(ids):
        return ids
    # spaced in value, not rank: a folder of mostly pale faces still gives its few dark ones
    chosen: list[str] = []
    for t in np.linspace(lightness[ids[0]], lightness[ids[-1]], n):
        chosen.append(min((k for k in ids if k not in chosen), key=lambda k: (abs(lightness[k] - t), k)))
    return sorted(chosen, key=lambda k: (lightness[k], k))


def portrait_clips(folder, out, n: int, *, progress=None) -> list[Path]:
    """``n`` still-pair clips (module docstring) in ``out/portraits/``, written when missing (atomically);
    every pair's :func:`portrait_stats` are cached in ``out/portraits/portraits.json``."""
    import json

    from ..io import atomic_path, read_image, write_video

    if n < 1:
        raise BadInputError(f"--portraits must be at least 1, got {n}")
    pairs = portrait_pairs(folder)
    dst_dir = Path(out) / "portraits"
    dst_dir.mkdir(parents=True, exist_ok=True)
    cache = dst_dir / "portraits.json"
    stats = {}
    if cache.is_file():
        stats = {k: {m: (float("nan") if v is None else float(v)) for m, v in d.items()}
                 for k, d in json.loads(cache.read_text(encoding="utf-8")).items()}
    todo = [k for k in pairs if k not in stats]
    for k in todo:
        stats[k] = portrait_stats(*pairs[k])
        if progress:
            progress(n=0, portrait=pairs[k][0].name)
    if todo:
        with atomic_path(cache) as tmp:
            Path(tmp).write_text(json.dumps({k: {m: (v if np.isfinite(v) else None) for m, v in d.items()}
                                             for k, d in sorted(stats.items())}, indent=1), encoding="utf-8")
    usable = [k for k in pairs if opens_with_smile(stats[k])]
    chosen = choose_portraits({k: stats[k]["lightness"] for k in usable}, n)
    if not chosen:
        raise BadInputError("no portrait pair with a closed neutral mouth and an open smile (dlib found no face, "
                            "or every smile is closed-lipped)", path=folder)
    paths = []
    for k in chosen:
        dst = dst_dir / f"portrait_{k}.mp4"
        if not dst.exists():
            neutral, smiling = (read_image(p) for p in pairs[k])
            if neutral.shape != smiling.shape:
                import cv2

                smiling = cv2.resize(smiling, neutral.shape[1::-1], interpolation=cv2.INTER_AREA)
            write_video(dst, [neutral] * HOLD + [smiling] * HOLD, FPS, overwrite=False)
        paths.append(dst)
    return paths
