"""The public puppetry API: :func:`puppeteer`."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Literal

from ..errors import BadInputError

if TYPE_CHECKING:  # pragma: no cover

    pass


from ._inputs import Progress, _progress
from ._persona import PersonaLike

__all__ = [
    "puppeteer",
]


def puppeteer(driver: str | os.PathLike, puppet: PersonaLike, output: str | os.PathLike, *,
              side_by_side: bool = False, size: int | None = None,
              mode: Literal["composite", "face"] = "composite", lighting: Literal["stats", "sh", "none"] = "stats",
              colour: Literal["driver", "persona"] = "driver",
              texture: Literal["ours", "static"] = "ours", weights: Literal["regional", "global"] = "regional",
              max_frames: int | None = None, driver_photos: str | os.PathLike | None = None,
              overwrite: bool = False, progress: Progress = False) -> dict:
    """Drive a persona's 3D face with another person's video (Suwajanakorn et al. 2015, §6).

    Parameters
    ----------
    driver : str or os.PathLike
        Driver video (MP4/MOV/MKV/AVI/MPG) showing one face.
    puppet : str, os.PathLike or Persona
        The puppet: a ``.persona`` file or a loaded persona.
    output : str or os.PathLike
        H.264 video to write (.mp4/.mov/.m4v/.mkv); the driver's audio is kept.
    side_by_side : bool
        Put the driver frame left of the puppet.
    size : int, optional
        Longer side of an output panel in px (default: the driver's).
    mode : {"composite", "face"}
        The puppet put into the driver's frame (its lighting, colour and face outline), or
        the puppet face alone on plain grey, as in the paper's figures.
    lighting : {"stats", "sh", "none"}
        Composite mode: match the driver's skin colour statistics, also its first-order
        spherical-harmonics lighting, or neither.
    colour : {"driver", "persona"}
        Composite mode: the puppet's skin takes the driver's colour and lighting, or keeps the
        persona's skin tone and takes only the driver's lighting.
    texture : {"ours", "static"}
        Expression-dependent texture or the static average.
    weights : {"regional", "global"}
        Expression weights of the texture: regional (mouth, eyes and the rest of the face
        each by their own fiducials, as :func:`persona_texture`) or the paper's global
        Eq. 2/3 weights (sigma 10).
    max_frames : int, optional
        Use only the first frames.
    driver_photos : str or os.PathLike, optional
        Folder of photos of the driver for its average shape (default: the video's frames).
    overwrite : bool
        Replace an existing output.
    progress : bool or callable
        True shows a tqdm bar.

    Returns
    -------
    dict
        The run's report: frames, lost_frames, fps, audio, timings, shape sources, output.

    Raises
    ------
    FileNotFoundError
        The driver or persona file does not exist.
    ValueError
        (:class:`facetex.NoFaceError`, :class:`facetex.BadVideoError`) no face in the video,
        unreadable video.
    OSError
        (:class:`facetex.OutputError`) the output cannot be written or exists.

    Examples
    --------
    >>> import facetex
    >>> facetex.puppeteer("clip.mp4", "george.persona", "puppet.mp4",
    ...                   side_by_side=True, progress=True)  # doctest: +SKIP
    """
    from ..io import video_info
    from ..puppet.composite import CompositeParams
    from ..puppet.puppetry import PuppetParams
    from ..puppet.puppetry import puppeteer as _puppeteer

    if texture not in ("ours", "static"):
        raise BadInputError(f"texture must be 'ours' or 'static', not {texture!r}")
    if weights not in ("regional", "global"):
        raise BadInputError(f"weights must be 'regional' or 'global', not {weights!r}")
    n = video_info(driver)["n_frames"] if progress is True else None
    if n is not None and max_frames is not None:
        n = min(n, max(0, int(max_frames)))
    with _progress(progress, None if n is None else 2 * n, "puppet", "frame") as bar:
        return _puppeteer(driver, puppet, output, driver_photos=driver_photos, side_by_side=side_by_side,
                          size=size, mode=mode, overwrite=overwrite, max_frames=max_frames,
                          params=PuppetParams(texture=texture, weights=weights,
                                              composite=CompositeParams(lighting=lighting, colour=colour)),
                          progress=bar)
