"""The public Python API: ``facetex.transfer``, ``facetex.build_persona``, ``facetex.puppeteer`` ...

Thin, documented entry points over the implementation subpackages: they take paths, PIL
images or numpy arrays, check them (one clear error naming what is wrong), pass explicit
keyword parameters to the implementation and return numpy arrays (float32 RGB in [0, 1],
(H, W, 3)). Nothing here computes an image itself.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator, Literal, Sequence, Union

import numpy as np

from ._args import check_device, check_seed
from .errors import BadImageError, BadInputError

if TYPE_CHECKING:  # pragma: no cover
    from PIL.Image import Image as PILImage

    from .persona.collection import Persona
    from .persona.params import TextureParams

__all__ = [
    "ImageLike", "as_image", "parse_iters", "transfer", "transfer_with_info", "transfer_step_image",
    "build_persona", "load_persona", "persona_texture", "texture_params", "persona_average", "persona_mesh", "Mesh",
    "puppeteer",
]

from .io import ImageLike, as_image  # noqa: E402  (re-exported: facetex.as_image)
Progress = Union[bool, Callable[..., None], None]

# --------------------------------------------------------------------------- inputs
_MAX_ITERS = 100_000
_MAX_LEVELS = 8


def parse_iters(iters: int | str | Sequence[int] | None, *, minimum: int = 1) -> tuple[int, ...] | None:
    """L-BFGS iterations per level from ``100``, ``"100,100,100"`` or ``(100, 100, 100)``.

    Parameters
    ----------
    iters : int, str, sequence of int or None
        One count (one level), comma-separated counts, or a sequence of counts.
    minimum : int
        Fewest iterations a level may have (the transfer functions accept 0: no L-BFGS step
        on that level, e.g. to look at the pre-warp alone).

    Returns
    -------
    tuple of int or None
        One count per resolution level (None when ``iters`` is None: the preset's).

    Raises
    ------
    ValueError
        (:class:`facetex.BadInputError`) not integers, a level below 1 iteration, more than
        8 levels or more than 100000 iterations in a level.

    Examples
    --------
    >>> import facetex
    >>> facetex.parse_iters("2,2,2")
    (2, 2, 2)
    """
    if iters is None:
        return None
    if isinstance(iters, str):
        parts = [p.strip() for p in iters.split(",")]
        try:
            vals = tuple(int(p) for p in parts)
        except ValueError:
            raise BadInputError(f"iters takes comma-separated integers such as '100,100,100', not {iters!r}") from None
    elif isinstance(iters, (int, np.integer)) and not isinstance(iters, bool):
        vals = (int(iters),)
    else:
        try:
            vals = tuple(iters)
        except TypeError:
            raise BadInputError(f"iters must be an integer, a list of integers or a string such as "
                                f"'100,100,100', not {iters!r}") from None
        if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in vals):
            raise BadInputError(f"iters must hold integers, not {iters!r}")
        vals = tuple(int(v) for v in vals)
    if not vals or any(v < minimum for v in vals):
        raise BadInputError(f"every level needs at least {minimum} iteration{'s' if minimum != 1 else ''}, "
                            f"not {iters!r}")
    if len(vals) > _MAX_LEVELS or any(v > _MAX_ITERS for v in vals):
        raise BadInputError(f"at most {_MAX_LEVELS} levels of at most {_MAX_ITERS} iterations, not {iters!r}")
    return vals


@contextmanager
def _progress(progress: Progress, total: int | None, desc: str, unit: str) -> Iterator[Callable | None]:
    """``progress=True``: a tqdm bar on stderr that stays when done; a callable is passed
    through; False/None: nothing."""
    if progress is True:
        import sys

        from tqdm import tqdm

        bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, dynamic_ncols=True, leave=True)

        def update(n: int = 1, **postfix):
            shown = {k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in postfix.items()
                     if isinstance(v, (int, float, str))}
            if shown:
                bar.set_postfix(shown, refresh=False)
            if bar.total is not None and bar.n + n > bar.total:  # the total is an estimate
                bar.total = bar.n + n
            bar.update(n)

        try:
            yield update
            if bar.total is not None and bar.n < bar.total:  # finished early: end at 100 %
                bar.total = bar.n
                bar.refresh()
        finally:
            bar.close()
    elif progress is None or progress is False:
        yield None
    elif callable(progress):
        yield progress
    else:
        raise BadInputError(f"progress must be True, False or a callable, not {progress!r}")


# -------------------------------------------------------------------------- transfer
_WEIGHTS = ("mrf_weight", "structure_weight", "content_weight", "style_weight", "tv_weight")


def _transfer_options(size, iters, texture_net, weights: dict, crop, detail, detail_strength,
                      options: dict, keep_shading=None, marks=None) -> dict:
    out = dict(options)
    if size is not None:
        out["size"] = int(size)
    it = parse_iters(iters, minimum=0)
    if it is not None:
        out["iters"] = it
    if texture_net is not None:
        out["texture_net"] = texture_net
    for k, v in weights.items():
        if v is not None:
            v = float(v)
            if not np.isfinite(v) or v < 0:
                raise BadInputError(f"{k} must be a finite number >= 0, not {v}")
            out[k] = v
    if crop is not None:
        out["crop"] = crop
    if detail is not None:
        out["detail"] = bool(detail)
    if detail_strength is not None:
        out["detail_strength"] = float(detail_strength)
    if keep_shading is not None:
        out["keep_shading"] = bool(keep_shading)
    if marks is not None:
        out["marks"] = marks
    return out


def transfer_params(method: str = "facetex", preset: str = "default", **options):
    """The :class:`facetex.transfer.TransferParams` a transfer with these arguments runs with."""
    from .transfer.methods import preset as make_preset

    options = dict(options)
    base = make_preset(method, preset, options.pop("texture_net", None))
    return base.with_options(**options)


def _init_arg(init, content: np.ndarray):
    if isinstance(init, str) and init in ("content", "random"):
        return init
    if isinstance(init, str) and not os.path.exists(init) and "/" not in init and "." not in init:
        raise BadInputError(f"init must be 'content', 'random', an image file or an (H, W, 3) array, not {init!r}")
    img = as_image(init, "init image")
    if img.shape != content.shape:
        raise BadImageError(f"init image is {img.shape[1]}x{img.shape[0]} px, the content "
                            f"{content.shape[1]}x{content.shape[0]}: it must have the content's size")
    return img


def _keep_large_uint8(image):
    """A uint8 RGB array over the pipeline's NATIVE_MAX_PIXELS, as it is (the pipeline makes only
    its reduced face region float: a 36 MP photo as float is 0.4 GB), else None."""
    from .transfer._pipeline import NATIVE_MAX_PIXELS

    if isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3 \
            and image.shape[0] * image.shape[1] > NATIVE_MAX_PIXELS:
        return image
    return None


def transfer_with_info(
    content: ImageLike,
    style: ImageLike,
    *,
    method: Literal["facetex", "mrf", "gatys"] = "facetex",
    preset: Literal["default", "paper", "preview"] = "default",
    size: int | None = None,
    iters: int | str | Sequence[int] | None = None,
    texture_net: Literal["effnet-lite0", "vgg19", "face-resnet"] | None = None,
    mrf_weight: float | None = None,
    structure_weight: float | None = None,
    content_weight: float | None = None,
    style_weight: float | None = None,
    tv_weight: float | None = None,
    crop: Literal["face", "image"] | None = None,
    detail: bool | None = None,
    detail_strength: float | None = None,
    keep_shading: bool | None = None,
    marks: Literal["content", "style", "off"] | None = None,
    init: Literal["content", "random"] | ImageLike = "content",
    seed: int = 0,
    device: str = "cpu",
    progress: Progress = False,
    callback: Callable[..., None] | None = None,
    save_every: int | None = None,
    content_points: np.ndarray | None = None,
    style_points: np.ndarray | None = None,
    max_memory: int | None = None,
    content_source: str | os.PathLike | None = None,
    style_source: str | os.PathLike | None = None,
    **options: Any,
) -> tuple[np.ndarray, dict]:
    """Transfer the skin texture of ``style`` onto ``content``, with the run's details.

    FaceTex (Kaur, Zhang & Dana 2017, Eq. 5) or one of its baselines: MRF-CNN (Eq. 7) and
    Gatys neural style (Eq. 6). The content person's identity is kept.

    Parameters
    ----------
    content, style : str, os.PathLike, PIL.Image.Image or numpy.ndarray
        The face whose identity is kept and the face whose texture is transferred: a file,
        a PIL image, or an (H, W, 3) array (uint8, or float in [0, 1]).
    method : {"facetex", "mrf", "gatys"}
        FaceTex (default), MRF-CNN or Neural Style.
    preset : {"default", "paper", "preview"}
        "default": a face crop at 384 px, up to 3 x 100 L-BFGS iterations (seconds on a CPU);
        "paper": the paper's whole-image 1000 px schedule; "preview": the default's steps at
        256 px and a few iterations, to choose a style.
    size : int, optional
        Long edge of the working region in px (32..4096); default the preset's.
    iters : int, str or sequence of int, optional
        L-BFGS iterations per resolution level: ``(100, 100, 100)`` or ``"100,100,100"``
        (0 on a level: no optimisation there).
    texture_net : {"effnet-lite0", "vgg19", "face-resnet"}, optional
        Texture feature network (default EfficientNet-Lite0, shipped weights).
    mrf_weight, structure_weight, content_weight, style_weight, tv_weight : float, optional
        Loss weights (normalised per level, see :mod:`facetex.transfer.methods`); default
        the method's and preset's.
    crop : {"face", "image"}, optional
        Work on a face crop and paste it back (default preset) or on the whole image.
    detail : bool, optional
        Run the native-resolution skin-detail stage (on in the default FaceTex preset).
    detail_strength : float, optional
        Strength of that stage, 0..2.
    keep_shading : bool, optional
        The output keeps the content's low-frequency skin colour and shading, the style
        brings only detail (on in the default FaceTex preset; off: the style's shading too).
    marks : {"content", "style", "off"}, optional
        Moles and spots: the content's kept ("content", the default FaceTex preset), the
        style's brought ("style"), or no marks step ("off").
    init : {"content", "random"} or image
        Where the optimisation starts: the content (FaceTex §2.3), uniform noise (seeded),
        or an image (path, PIL or array) of the content's size.
    seed : int
        Random seed; CPU runs are bit-reproducible for a given seed.
    device : str
        torch device: "cpu", "cuda", "cuda:N".
    progress : bool or callable
        True shows a tqdm progress bar on stderr; a callable gets
        ``progress(n=1, level=, loss=, terms=)`` per loss evaluation (terms: each
        weighted loss term's value).
    callback : callable, optional
        ``callback(image=, level=, evaluation=)`` every ``save_every`` loss evaluations and
        after each level, with the working region's image at that level's resolution
        (see :func:`transfer_step_image` for a full-size image).
    save_every : int, optional
        Period of ``callback`` in loss evaluations.
    content_points, style_points : numpy.ndarray, optional
        (68, 2) landmarks (x, y) of the faces, when already known (saves a detection).
    max_memory : int, optional
        Refuse a job whose estimated peak exceeds this many bytes (default 75 % of free RAM).
    content_source, style_source : str or os.PathLike, optional
        Names of the images for error messages when they are given as arrays (default:
        their paths when given as paths).
    **options
        Any other field of :class:`facetex.transfer.TransferParams` (e.g. ``levels``,
        ``patch_size``, ``constraint``).

    Returns
    -------
    image : numpy.ndarray
        The output, float32 (H, W, 3) in [0, 1] at the content's size.
    info : dict
        Parameters, seed, timings, per-level losses, the working region ``region_box``
        (x0, y0, x1, y1) and, under ``"images"``, the working-region images.

    Raises
    ------
    ValueError
        (:class:`facetex.BadInputError`, :class:`facetex.BadImageError`,
        :class:`facetex.NoFaceError`) a bad argument, an unusable image, no face found.
    FileNotFoundError
        An input file does not exist.
    facetex.MemoryBudgetError
        The job would need more than ``max_memory`` bytes.

    Examples
    --------
    >>> import facetex
    >>> out, info = facetex.transfer_with_info("content.jpg", "style.jpg", iters="20,20,20",
    ...                                        size=256)  # doctest: +SKIP
    >>> info["timings"]["total_s"]  # doctest: +SKIP
    41.2
    """
    from .transfer._pipeline import transfer_with_info as _run

    if content_source is None and isinstance(content, (str, os.PathLike)):
        content_source = os.fspath(content)
    if style_source is None and isinstance(style, (str, os.PathLike)):
        style_source = os.fspath(style)
    weights = dict(mrf_weight=mrf_weight, structure_weight=structure_weight, content_weight=content_weight,
                   style_weight=style_weight, tv_weight=tv_weight)
    opts = _transfer_options(size, iters, texture_net, weights, crop, detail, detail_strength, options,
                             keep_shading=keep_shading, marks=marks)
    params = transfer_params(method, preset, **opts)  # bad options fail before any image is read
    if save_every is not None and (not isinstance(save_every, (int, np.integer)) or save_every < 1):
        raise BadInputError(f"save_every must be a positive integer, not {save_every!r}")
    seed, device = check_seed(seed), check_device(device)
    c, s = _keep_large_uint8(content), _keep_large_uint8(style)
    if c is None:
        c = as_image(content, "content image" + (f" {content_source}" if content_source else ""))
    if s is None:
        s = as_image(style, "style image" + (f" {style_source}" if style_source else ""))
    start = _init_arg(init, c)
    total = int(sum(params.iters) * params.eval_budget) + params.levels  # the evaluation budget per level
    with _progress(progress, total, method, "eval") as bar:
        return _run(c, s, method=method, preset=preset, seed=seed, device=device, progress=bar,
                    callback=callback, save_every=save_every, content_points=content_points,
                    style_points=style_points, content_source=content_source, style_source=style_source,
                    max_memory=max_memory, init=start, **opts)


def transfer(
    content: ImageLike,
    style: ImageLike,
    *,
    method: Literal["facetex", "mrf", "gatys"] = "facetex",
    preset: Literal["default", "paper", "preview"] = "default",
    size: int | None = None,
    iters: int | str | Sequence[int] | None = None,
    texture_net: Literal["effnet-lite0", "vgg19", "face-resnet"] | None = None,
    mrf_weight: float | None = None,
    structure_weight: float | None = None,
    content_weight: float | None = None,
    style_weight: float | None = None,
    tv_weight: float | None = None,
    crop: Literal["face", "image"] | None = None,
    detail: bool | None = None,
    detail_strength: float | None = None,
    keep_shading: bool | None = None,
    marks: Literal["content", "style", "off"] | None = None,
    init: Literal["content", "random"] | ImageLike = "content",
    seed: int = 0,
    device: str = "cpu",
    progress: Progress = False,
    callback: Callable[..., None] | None = None,
    save_every: int | None = None,
    content_points: np.ndarray | None = None,
    style_points: np.ndarray | None = None,
    max_memory: int | None = None,
    **options: Any,
) -> np.ndarray:
    """Transfer the skin texture of ``style`` onto ``content`` (FaceTex or a baseline).

    The same as :func:`transfer_with_info`, returning only the image.

    Parameters
    ----------
    content, style : str, os.PathLike, PIL.Image.Image or numpy.ndarray
        The face whose identity is kept and the face whose texture is transferred.
    method : {"facetex", "mrf", "gatys"}
        FaceTex (Eq. 5, default), MRF-CNN (Eq. 7) or Neural Style (Eq. 6).
    preset : {"default", "paper", "preview"}
        The default 384 px face-crop schedule, the paper's 1000 px whole-image one, or a quick
        256 px preview.
    size : int, optional
        Long edge of the working region in px.
    iters : int, str or sequence of int, optional
        L-BFGS iterations per level, e.g. ``"100,100,100"``.
    texture_net : {"effnet-lite0", "vgg19", "face-resnet"}, optional
        Texture feature network.
    mrf_weight, structure_weight, content_weight, style_weight, tv_weight : float, optional
        Loss weights (default the method's).
    crop : {"face", "image"}, optional
        Face crop or whole image.
    detail : bool, optional
        Native-resolution skin-detail stage on/off.
    detail_strength : float, optional
        Its strength, 0..2.
    keep_shading : bool, optional
        Keep the content's low-frequency skin colour and shading (default preset: on).
    marks : {"content", "style", "off"}, optional
        Keep the content's marks or bring the style's (default preset: "content").
    init : {"content", "random"} or image
        Start of the optimisation.
    seed : int
        Random seed.
    device : str
        torch device.
    progress : bool or callable
        True: a tqdm bar on stderr.
    callback : callable, optional
        ``callback(image=, level=, evaluation=)`` every ``save_every`` evaluations.
    save_every : int, optional
        Period of ``callback``.
    content_points, style_points : numpy.ndarray, optional
        Known (68, 2) landmarks.
    max_memory : int, optional
        Memory budget in bytes.
    **options
        Other :class:`facetex.transfer.TransferParams` fields.

    Returns
    -------
    numpy.ndarray
        The output, float32 (H, W, 3) in [0, 1] at the content's size.

    Raises
    ------
    ValueError
        Bad argument, unusable image, no face (:class:`facetex.FacetexError` subclasses).
    FileNotFoundError
        An input file does not exist.
    facetex.MemoryBudgetError
        Over ``max_memory``.

    Examples
    --------
    >>> import facetex
    >>> out = facetex.transfer("content.jpg", "style.jpg", method="facetex", size=256,
    ...                        iters="30,30,30", seed=0, progress=True)  # doctest: +SKIP
    >>> facetex.write_image("out.png", out)  # doctest: +SKIP
    """
    return transfer_with_info(
        content, style, method=method, preset=preset, size=size, iters=iters, texture_net=texture_net,
        mrf_weight=mrf_weight, structure_weight=structure_weight, content_weight=content_weight,
        style_weight=style_weight, tv_weight=tv_weight, crop=crop, detail=detail, detail_strength=detail_strength,
        keep_shading=keep_shading, marks=marks, init=init, seed=seed, device=device, progress=progress,
        callback=callback, save_every=save_every,
        content_points=content_points, style_points=style_points, max_memory=max_memory, **options)[0]


def transfer_step_image(content: np.ndarray, image: np.ndarray, box: Sequence[int], *,
                        feather: bool = True) -> np.ndarray:
    """A full-size picture of an intermediate transfer step.

    The transfer's ``callback`` gets the working region (the face crop) at the current
    level's resolution; this pastes the *change* it made (upscaled) into the full-size
    content, as the final output is pasted.

    Parameters
    ----------
    content : numpy.ndarray
        The full content image, float32 (H, W, 3).
    image : numpy.ndarray
        The callback's image: the working region at some resolution.
    box : sequence of int
        The working region (x0, y0, x1, y1) in ``content`` (``info["region_box"]``, or
        :func:`facetex.transfer.face_crop_box` of the content's landmarks).
    feather : bool
        Blend the crop's inner edges over 8 % of its size (as the face-crop preset does).

    Returns
    -------
    numpy.ndarray
        The full-size image, float32 (H, W, 3) in [0, 1], the content's size.
    """
    import cv2

    x0, y0, x1, y1 = (int(v) for v in box)
    region = content[y0:y1, x0:x1]
    rh, rw = region.shape[:2]
    img = np.asarray(image, np.float32)
    h, w = img.shape[:2]
    base = cv2.resize(region, (w, h), interpolation=cv2.INTER_AREA if w < rw else cv2.INTER_CUBIC)
    delta = cv2.resize(img - base, (rw, rh), interpolation=cv2.INTER_CUBIC)
    new = np.clip(region + delta, 0.0, 1.0)
    out = np.array(content, np.float32, copy=True)
    H, W = out.shape[:2]
    if feather and (x0, y0, x1, y1) != (0, 0, W, H):
        r = max(2, int(0.08 * min(rh, rw)))
        ramp = (np.arange(r, dtype=np.float32) + 0.5) / r
        ay, ax = np.ones(rh, np.float32), np.ones(rw, np.float32)
        if y0 > 0:
            ay[:r] = np.minimum(ay[:r], ramp)
        if y1 < H:
            ay[-r:] = np.minimum(ay[-r:], ramp[::-1])
        if x0 > 0:
            ax[:r] = np.minimum(ax[:r], ramp)
        if x1 < W:
            ax[-r:] = np.minimum(ax[-r:], ramp[::-1])
        a = np.outer(ay, ax)[..., None]
        new = a * new + (1 - a) * region
    out[y0:y1, x0:x1] = new
    return out


# --------------------------------------------------------------------------- persona
PersonaLike = Union[str, os.PathLike, "Persona"]


def _persona(persona: PersonaLike) -> "Persona":
    if isinstance(persona, (str, os.PathLike)):
        return load_persona(persona)
    if hasattr(persona, "images") and hasattr(persona, "fiducials"):
        return persona
    raise BadInputError(f"persona must be a .persona path or a Persona, not {type(persona).__name__}")


def build_persona(photo_dir: str | os.PathLike, *, jobs: int = 2, min_photos: int = 10,
                  allow_mixed: bool = False, files: Sequence[str | os.PathLike] | None = None,
                  progress: Progress = False) -> "Persona":
    """Build a persona from a folder of photos of one person (Suwajanakorn et al. 2015, §4-5).

    Every photo is detected, frontalized and pose-corrected; the usable ones are aligned to
    their mean (TPS + collection flow) and the average 3D face is reconstructed.

    Parameters
    ----------
    photo_dir : str or os.PathLike
        Folder of JPEG/PNG photos of one person (>= ``min_photos`` usable).
    jobs : int
        Worker processes.
    min_photos : int
        Fewest usable photos accepted.
    allow_mixed : bool
        Keep all photos even when they show several people (default: photos of other people
        are left out when one person has >= 80 % of them, otherwise the build is refused).
    files : sequence of paths, optional
        Use only these files of the folder (e.g. a leave-out evaluation).
    progress : bool or callable
        True shows a tqdm bar.

    Returns
    -------
    facetex.persona.Persona
        Save it with ``persona.save("NAME.persona")``.

    Raises
    ------
    FileNotFoundError
        The folder does not exist.
    ValueError
        (:class:`facetex.BadInputError`) too few usable photos, or photos of several people.

    Examples
    --------
    >>> import facetex
    >>> p = facetex.build_persona("photos/george", jobs=2, progress=True)  # doctest: +SKIP
    >>> p.save("george.persona")  # doctest: +SKIP
    """
    from .io import check_input_dir
    from .persona import PersonaParams
    from .persona import build_persona as _build
    from .persona.build import _list_photos

    folder = check_input_dir(photo_dir, BadInputError, what="photo folder")
    n = len(files) if files is not None else len(_list_photos(folder))
    from .persona.build import SHAPE_STEPS

    # two passes over the photos, then the average shape's steps (each stage named on the bar)
    with _progress(progress, 2 * n + SHAPE_STEPS, "persona", "step") as bar:
        return _build(folder, jobs=int(jobs), progress=bar, params=PersonaParams(min_photos=int(min_photos)),
                      files=files, allow_mixed=allow_mixed)


def load_persona(path: str | os.PathLike) -> "Persona":
    """Read a ``.persona`` file written by :func:`build_persona` / ``facetex persona build``.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    facetex.persona.Persona
        The person's photos, landmarks, flows, shape and texture stacks.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ValueError
        (:class:`facetex.BadPersonaError`) corrupt, another format or a newer version.

    Examples
    --------
    >>> import facetex
    >>> p = facetex.load_persona("george.persona")  # doctest: +SKIP
    >>> len(p)  # usable photos  # doctest: +SKIP
    519
    """
    from .errors import BadPersonaError, PersonaNotFoundError
    from .io import as_path
    from .persona import load_persona as _load

    path = as_path(path, BadPersonaError, "persona file")
    if not os.path.lexists(path):
        raise PersonaNotFoundError("persona file not found: build one with `facetex persona build`", path=path)
    return _load(path)


def persona_texture(persona: PersonaLike, *, like: ImageLike | None = None,
                    fiducials: np.ndarray | Sequence[Sequence[float]] | None = None,
                    method: Literal["ours", "static", "weighted", "prewarp"] = "ours",
                    weights: Literal["regional", "global"] = "regional", sigma: float | None = None,
                    neighbours: int | None = None, progress: Progress = False) -> np.ndarray:
    """The persona's face texture for a target expression (Suwajanakorn et al. 2015, Eq. 3).

    Parameters
    ----------
    persona : str, os.PathLike or Persona
        A ``.persona`` file or a loaded persona.
    like : image, optional
        A reference photo (path, PIL or array) whose expression is wanted.
    fiducials : array_like, optional
        Or the target's 49 (or 68) (x, y) fiducials in the persona's canonical frame.
    method : {"ours", "static", "weighted", "prewarp"}
        The paper's expression-weighted multi-scale blend ("ours") or a Fig. 5 baseline.
    weights : {"regional", "global"}
        Expression weights: regional (mouth, eyes and the rest of the face each weighted by
        their own normalised fiducials, blended spatially) or global (the paper's Eq. 2/3:
        all fiducials, one ``sigma``, Laplacian exponent alpha 1).
    sigma : float, optional
        ``weights="global"`` only: expression-similarity sigma of Eq. 2/3 (default 10,
        typically 6-12).
    neighbours : int, optional
        ``weights="regional"`` only: each region's sigma is the target's distance to its
        K-th nearest photo / 2 (default 3).
    progress : bool or callable
        True shows a tqdm bar.

    Returns
    -------
    numpy.ndarray
        The texture, float32 (H, W, 3) in [0, 1] in the canonical frame.

    Raises
    ------
    ValueError
        Neither or both of ``like`` and ``fiducials``; bad fiducials; no face in ``like``;
        ``sigma`` with regional weights or ``neighbours`` with global ones.

    Examples
    --------
    >>> import facetex
    >>> tex = facetex.persona_texture("george.persona", like="smiling.jpg")  # doctest: +SKIP
    >>> paper = facetex.persona_texture("george.persona", like="smiling.jpg",
    ...                                 weights="global", sigma=10)  # doctest: +SKIP
    """
    from .persona import synthesize_texture

    if (like is None) == (fiducials is None):
        raise BadInputError("give exactly one of like= (a reference photo) and fiducials=")
    tp = texture_params(weights=weights, sigma=sigma, neighbours=neighbours)
    p = _persona(persona)
    kw: dict[str, Any] = {}
    if like is not None:
        kw["reference"] = like if isinstance(like, (str, os.PathLike)) else as_image(like, "reference image")
    else:
        kw["fiducials"] = np.asarray(fiducials, np.float64)
    with _progress(progress, None, "texture", "step") as bar:
        return synthesize_texture(p, method=method, params=tp, progress=bar, **kw)


def texture_params(*, weights: Literal["regional", "global"] = "regional", sigma: float | None = None,
                   neighbours: int | None = None) -> "TextureParams":
    """Persona texture parameters from the user-facing options, checked.

    Parameters
    ----------
    weights : {"regional", "global"}
        Regional expression weights (ours) or the paper's global Eq. 2/3 weights.
    sigma : float, optional
        Global weights only: sigma of Eq. 2/3 (default 10).
    neighbours : int, optional
        Regional weights only: K of the adaptive per-region sigma (default 3).

    Returns
    -------
    facetex.persona.TextureParams
        The options, validated, for :func:`persona_texture` and :func:`facetex.puppeteer`.

    Raises
    ------
    ValueError
        (:class:`facetex.BadInputError`) an unknown ``weights``, a non-positive ``sigma`` or
        ``neighbours``, or an option that does not apply to ``weights``.

    Examples
    --------
    >>> import facetex
    >>> facetex.texture_params(weights="global", sigma=8).sigma
    8.0
    """
    import math

    from .persona import WEIGHTS, TextureParams

    if weights not in WEIGHTS:
        raise BadInputError(f"weights must be one of {', '.join(map(repr, WEIGHTS))}, not {weights!r}")
    kw: dict[str, Any] = {"weights": weights}
    if sigma is not None:
        if weights != "global":
            raise BadInputError("sigma applies to the paper's global weights (weights='global'); the regional "
                                "weights measure their own sigma: set neighbours instead")
        try:
            s = float(sigma)
        except (TypeError, ValueError):
            s = math.nan
        if not (math.isfinite(s) and s > 0):
            raise BadInputError(f"sigma must be a positive number (typically 6-12), not {sigma!r}")
        kw["sigma"] = s
    if neighbours is not None:
        if weights != "regional":
            raise BadInputError("neighbours applies to the regional weights (weights='regional'); the global "
                                "weights take sigma")
        if not isinstance(neighbours, (int, np.integer)) or isinstance(neighbours, bool) or neighbours < 1:
            raise BadInputError(f"neighbours must be a positive integer, not {neighbours!r}")
        kw["neighbours"] = int(neighbours)
    return TextureParams(**kw)


def persona_average(persona: PersonaLike, *, stage: Literal["a", "b", "c", "d"] = "d") -> np.ndarray:
    """The persona's average face (Suwajanakorn et al. 2015, Fig. 6 stages a-d).

    Parameters
    ----------
    persona : str, os.PathLike or Persona
        A ``.persona`` file or a loaded persona.
    stage : {"a", "b", "c", "d"}
        a: frontalized, b: + TPS, c: + dense warp, d: + multi-scale blend.

    Returns
    -------
    numpy.ndarray
        The texture, float32 (H, W, 3) in [0, 1] in the canonical frame.

    Raises
    ------
    ValueError
        Unknown stage or a bad persona file.

    Examples
    --------
    >>> import facetex
    >>> avg = facetex.persona_average("george.persona", stage="d")  # doctest: +SKIP
    """
    from .persona import average_face

    if stage not in ("a", "b", "c", "d"):
        raise BadInputError(f"stage must be 'a', 'b', 'c' or 'd', not {stage!r}")
    return average_face(_persona(persona), stage)


@dataclass
class Mesh:
    """A textured triangle mesh and where its depth came from.

    Parameters
    ----------
    vertices : numpy.ndarray
        (n, 3) in canonical px (OBJ axes: x right, y up, z towards the viewer).
    faces : numpy.ndarray
        (m, 3) vertex indices.
    uv : numpy.ndarray
        (n, 2) texture coordinates in [0, 1].
    texture : numpy.ndarray
        (H, W, 3) float32.
    depth_source : {"collection", "generic"}
        The person's photometric-stereo shape or the generic one.
    depth_origin : {"stored", "computed"} or None
        "stored" (validated at build time), "computed" (an older persona, reconstructed and
        validated now) or None (generic on request).
    depth_photos : int
        Photos the shape was reconstructed from.
    shape_reason : str
        Why that shape was used.
    shape_validation : dict or None
        The photometric validation's numbers and verdict (None with ``shape="generic"``).
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    texture: np.ndarray
    depth_source: str
    depth_origin: str | None
    depth_photos: int
    shape_reason: str = ""
    shape_validation: dict | None = None

    def save(self, path: str | os.PathLike, *, overwrite: bool = False, inputs=(),
             extra_files: dict | None = None) -> Path:
        """Write ``path`` (.obj) with its ``.mtl`` and ``.png`` texture beside it (and
        ``extra_files``, {path: bytes}), all or none."""
        from .errors import OutputError
        from .puppet.mesh_io import write_obj

        path = Path(path)
        if path.suffix.lower() != ".obj":
            raise OutputError("mesh file name must end in .obj", path=path)
        write_obj(path, self.vertices, self.faces, self.uv, self.texture, overwrite=overwrite, inputs=inputs,
                  extra_files=extra_files)
        return path


def persona_mesh(persona: PersonaLike, *, step: int = 1,
                 shape: Literal["collection", "generic"] = "collection") -> Mesh:
    """The persona's average 3D face as a textured mesh (Suwajanakorn et al. 2015, §4).

    Parameters
    ----------
    persona : str, os.PathLike or Persona
        A ``.persona`` file or a loaded persona.
    step : int
        Grid step in canonical px (1 = every pixel; at most 1/8 of the frame width).
    shape : {"collection", "generic"}
        The persona's photometric-stereo average depth when it passed its photometric
        validation on held-out photos (else the generic face, and ``mesh.shape_reason``
        says why) or the generic face.

    Returns
    -------
    Mesh
        ``mesh.save("face.obj")`` writes the .obj, .mtl and .png texture;
        ``mesh.depth_source``, ``mesh.shape_reason`` and ``mesh.shape_validation`` say
        which shape was used and why.

    Raises
    ------
    ValueError
        A step that leaves too few grid points, an unknown shape.

    Examples
    --------
    >>> import facetex
    >>> facetex.persona_mesh("george.persona", step=2).save("face.obj")  # doctest: +SKIP
    """
    from .persona import average_face
    from .persona.align import face_region
    from .persona.build import average_shape
    from .puppet.mesh_io import depth_to_mesh
    from .puppet.shape import checked_depth, generic_depth_px

    if shape not in ("collection", "generic"):
        raise BadInputError(f"shape must be 'collection' or 'generic', not {shape!r}")
    p = _persona(persona)
    W, H = p.size if hasattr(p, "size") else p.params.size
    max_step = max(1, min(W, H) // 8)
    if not isinstance(step, (int, np.integer)) or not 1 <= step <= max_step:
        raise BadInputError(f"step {step} leaves too few grid points in the {W}x{H} canonical frame: "
                            f"use 1..{max_step}")
    region = face_region(p.points68.mean(axis=0), (H, W))
    origin, n_used, validation = None, 0, None
    if shape == "generic":
        depth, source = generic_depth_px((W, H)).astype("float64"), "generic"
        reason = "generic face on request (shape='generic')"
    else:
        if p.shape_report is not None:  # reconstructed and validated at build time
            raw, n_used, origin, validation = p.depth, p.depth_photos, "stored", p.shape_report
        else:  # a version-1 persona, or one built before the validation: reconstruct and validate now
            raw, n_used, validation = average_shape(p)
            origin = "computed"
        if not validation.get("accepted"):
            raw, n_used = None, 0
        depth, source = checked_depth(raw, region, (W, H))
        if source == "collection":
            reason = validation.get("reason", "")
        elif not validation.get("accepted"):
            reason = f"generic face: {validation.get('reason', 'the shape was rejected')}"
        else:
            reason = ("generic face: the validated depth is implausible (RMS difference to the generic face "
                      "above 8 % of the frame width)")
    vertices, faces, uv = depth_to_mesh(depth, region, step=int(step))
    if len(faces) == 0:
        raise BadInputError(f"step {step} leaves no triangle on the face: use a smaller step")
    return Mesh(vertices, faces, uv, average_face(p, "d"), source, origin, int(n_used), reason, validation)


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
    from .io import video_info
    from .puppet.composite import CompositeParams
    from .puppet.puppetry import PuppetParams
    from .puppet.puppetry import puppeteer as _puppeteer

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
