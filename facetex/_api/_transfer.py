"""The public FaceTex API: :func:`transfer`, :func:`transfer_with_info`, :func:`transfer_step_image`."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, Callable, Literal, Sequence

import numpy as np

from .._args import check_device, check_seed
from ..errors import BadInputError

if TYPE_CHECKING:  # pragma: no cover

    pass


from ..io import ImageLike, as_image
from ._inputs import Progress, _progress, parse_iters

__all__ = [
    "transfer",
    "transfer_with_info",
    "transfer_step_image",
    "transfer_params",
]


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
    from ..transfer.methods import preset as make_preset

    options = dict(options)
    base = make_preset(method, preset, options.pop("texture_net", None))
    return base.with_options(**options)


def _init_arg(init, content: np.ndarray):
    if isinstance(init, str) and init in ("content", "random"):
        return init
    if isinstance(init, str) and not os.path.exists(init) and "/" not in init and "." not in init:
        raise BadInputError(f"init must be 'content', 'random', an image file or an (H, W, 3) array, not {init!r}")
    from ..transfer._regions import _init_image

    return _init_image(as_image(init, "init image"), content)  # the pipeline's own size check


def _keep_large(image, name: str):
    """A uint8 or float RGB array over the pipeline's NATIVE_MAX_PIXELS, as it is (the pipeline makes
    only its reduced face region float32, and the output: a 36 MP photo as float32 is 0.4 GB, a
    6000 x 6000 float64 array's float32 copy 0.4 GB), else None. A float array's values are checked
    here, as :func:`facetex.io.as_image` would (in row strips, without copies)."""
    from ..io import check_float_pixels
    from ..transfer._regions import stays_float, stays_integer

    if stays_integer(image) and image.dtype == np.uint8:
        return image
    if stays_float(image):
        check_float_pixels(image, name)
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
    from ..transfer._pipeline import transfer_with_info as _run

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
    c_name = "content image" + (f" {content_source}" if content_source else "")
    s_name = "style image" + (f" {style_source}" if style_source else "")
    c, s = _keep_large(content, c_name), _keep_large(style, s_name)
    if c is None:
        c = as_image(content, c_name)
    if s is None:
        s = as_image(style, s_name)
    start = _init_arg(init, c)
    # as_image's copy of a caller's array (or a file's pixels) is ours: a large content's output is
    # pasted into it instead of into another copy (issue 23: a 6000 x 6000 float64 array was held
    # as two float32 copies besides the caller's; a float array is now kept as it is, see _keep_large)
    owned = c is not content and not (isinstance(content, np.ndarray) and np.may_share_memory(c, content))
    total = int(sum(params.iters) * params.eval_budget) + params.levels  # the evaluation budget per level
    with _progress(progress, total, method, "eval") as bar:
        return _run(c, s, method=method, preset=preset, seed=seed, device=device, progress=bar, _content_owned=owned,
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


