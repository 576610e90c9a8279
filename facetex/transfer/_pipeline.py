"""The FaceTex transfer pipeline: landmarks → region → style pre-warp → masks → losses → L-BFGS.

Data flow (FaceTex §2.3 and §3.1)::

    content, style ──landmarks──> working region (face crop or whole image, long edge = size)
    style ──align_style_to_content (Beier–Neely morph + SIFT-flow refinement)──> style_w
    masks: facial prior × face region (gradient scaling, Sec. 2.2), face region (style patches)
    optimize_image(content_w, per-level losses) ──> paste back into the full content image
"""

from __future__ import annotations

import time
import warnings
from dataclasses import asdict

import cv2
import numpy as np
import torch

from ..errors import BadInputError, MemoryBudgetError
from ._levels import _LossBuilder, default_max_memory, estimate_transfer_memory
from ._regions import (
    NATIVE_MAX_PIXELS,
    _check_rgb,
    _compose,
    _full_box,
    _init_image,
    _map_points,
    _native_part,
    _paste,
    _paste_change,
    _paste_region,
    _resize,
    detect_points68,
    face_crop_box,
)
from .methods import preset as make_preset
from .methods import working_shape
from .optimize import _resize as _resize_level
from .optimize import optimize_image


def _transfer_reduced(content, style, cp, sp, params, init, callback, kwargs,
                      content_owned: bool = False) -> tuple[np.ndarray, dict]:
    """:func:`transfer_with_info` of a content or style over NATIVE_MAX_PIXELS (see there);
    ``content_owned``: the output is pasted into ``content`` itself (see :func:`_paste_change`)."""
    c_part, c_sub, c_pts, c_scale = (((0, 0, content.shape[1], content.shape[0]), content, cp, (1.0, 1.0))
                                     if content.shape[0] * content.shape[1] <= NATIVE_MAX_PIXELS
                                     else _native_part(content, cp, params.crop))
    s_sub, s_pts = style, sp
    if style.shape[0] * style.shape[1] > NATIVE_MAX_PIXELS:
        _, s_sub, s_pts, _ = _native_part(style, sp, params.crop)
    if not (isinstance(init, str) and init in ("content", "random")):
        ini = _init_image(init, content)[c_part[1]:c_part[3], c_part[0]:c_part[2]]
        init = ini if ini.shape == c_sub.shape else _resize(ini, (c_sub.shape[1], c_sub.shape[0]))
    wrapped = None
    if callback is not None:
        def wrapped(image, level, evaluation, full_image, box):
            callback(image=image, level=level, evaluation=evaluation,
                     full_image=_paste_change(content, c_part, c_scale, c_sub, full_image, box),
                     box=_full_box(c_part, c_scale, box, content.shape))
    for name, (big, sub) in {"content": (content, c_sub), "style": (style, s_sub)}.items():
        if sub is not big:
            warnings.warn(f"{name} image is {big.shape[1]}x{big.shape[0]} px: worked on "
                          f"{'its face region' if params.crop == 'face' else 'it'} at {sub.shape[1]}x{sub.shape[0]} "
                          f"(at most {NATIVE_MAX_PIXELS / 1e6:g} megapixels)"
                          + ("; the change is pasted at full resolution" if name == "content" else ""), stacklevel=3)
    out_sub, info = transfer_with_info(c_sub, s_sub, content_points=c_pts, style_points=s_pts, init=init,
                                       callback=wrapped, **kwargs)
    box_small = info["region_box"]
    out = out_sub if c_sub is content else _paste_change(content, c_part, c_scale, c_sub, out_sub, box_small,
                                                         in_place=content_owned)
    info["region_box"] = list(map(int, _full_box(c_part, c_scale, box_small, content.shape)))
    info["reduced"] = {"content_part": list(map(int, c_part)), "content_scale": [float(v) for v in c_scale],
                       "content_work_shape": list(c_sub.shape[:2]), "style_work_shape": list(s_sub.shape[:2]),
                       "max_pixels": NATIVE_MAX_PIXELS}
    return out, info


# ---------------------------------------------------------------- masks and pre-warp
def _face_mesh(image, points68):
    """MediaPipe mesh of the face at ``points68``, or None when the mesh finds no face there
    (the skin mask then falls back to the landmark outline). A missing model file (a wheel
    built offline, without the model) also falls back, with a warning: the skin mask, and so
    the output, then differ from a full install's."""
    import warnings

    from ..errors import FacetexError, ModelNotFoundError
    from ..landmarks import face_mesh468

    try:
        return face_mesh468(image, points68)
    except ModelNotFoundError as e:
        warnings.warn(f"face-mesh model unavailable ({e}); the skin mask falls back to the 68-landmark "
                      "outline and results differ from a full install", RuntimeWarning, stacklevel=2)
        return None
    except FacetexError:
        return None


def _crop_map_energies(style, style_map, face_width_style, dparams):
    """The style's band energies (detail stage) computed on the part of the style the map
    reads from, then carried into the content frame through the map."""
    from ..geometry.morph import remap
    from .detail import style_band_energies

    h, w = style.shape[:2]
    pad = int(np.ceil(6 * max(dparams.sigmas) * face_width_style / 330.0)) + 4
    x0 = int(max(0, np.floor(style_map[..., 0].min()) - pad))
    x1 = int(min(w, np.ceil(style_map[..., 0].max()) + pad + 1))
    y0 = int(max(0, np.floor(style_map[..., 1].min()) - pad))
    y1 = int(min(h, np.ceil(style_map[..., 1].max()) + pad + 1))
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    energies = style_band_energies(style[y0:y1, x0:x1], face_width=face_width_style, params=dparams)
    shifted = (style_map - np.array([x0, y0], np.float32)).astype(np.float32)
    return [remap(e, shifted, border="replicate") for e in energies]


# ---------------------------------------------------------------- public API
def transfer_with_info(content, style, *, method: str = "facetex", preset: str = "default", seed: int = 0, device: str = "cpu", progress=None,
                       callback=None, save_every: int | None = None, content_points=None, style_points=None,
                       content_source=None, style_source=None, max_memory: int | None = None,
                       init="content", _content_owned: bool = False, **options) -> tuple[np.ndarray, dict]:
    """Transfer the skin texture of ``style`` onto ``content`` (FaceTex, or a baseline).

    ``content``/``style``: (H, W, 3) RGB, float in [0, 1] or uint8. ``method``: "facetex"
    (Eq. 5), "mrf" (Eq. 7) or "gatys" (Eq. 6); ``preset``: "default" or "paper"; any
    :class:`TransferParams` field may be overridden as a keyword (``size``, ``iters``,
    ``texture_net``, ``structure_weight`` …). Returns the output at the content's size and
    an info dict (parameters, timings, per-level loss terms, pre-warp folds, and under
    ``"images"`` the working-region images: content, pre-warped style at native and working
    resolution, skin masks, the optimiser's output). ``progress(n=1, level=, loss=, terms=)`` is
    called per loss evaluation; ``callback(image=, level=, evaluation=, full_image=, box=)``
    every ``save_every`` evaluations and after each level: ``image`` is the working region at
    the level's size, ``full_image`` the full-size picture of that step (pasted as the output
    is, before the detail stage), ``box`` the region in the content.
    ``init``: where the optimisation starts — "content" (FaceTex §2.3), "random" (uniform
    noise in [0, 1], seeded, in the pixels that may change), or an (H, W, 3) image of the
    content's size.
    A content or style over :data:`NATIVE_MAX_PIXELS` is worked on around its face, reduced to
    that many pixels, and the change is pasted into the content at full resolution (a warning
    says so; ``info["reduced"]`` records it).
    ``_content_owned`` (the public API's): ``content`` is a float32 copy made for this call, and
    a large one becomes the output (the change pasted into it) instead of being copied again.
    Raises NoFaceError (naming ``*_source``), MemoryBudgetError above ``max_memory`` bytes.
    """
    from .. import __version__

    t_start = time.perf_counter()
    texture_net = options.pop("texture_net", None)
    base = make_preset(method, preset, texture_net)
    params = base.with_options(**options)
    content = _check_rgb(content, f"content image{'' if content_source is None else ' ' + str(content_source)}",
                         lazy=True)
    style = _check_rgb(style, f"style image{'' if style_source is None else ' ' + str(style_source)}", lazy=True)
    timings = {}
    t0 = time.perf_counter()
    cp = detect_points68(content, content_source) if content_points is None else np.asarray(content_points, float)
    sp = detect_points68(style, style_source) if style_points is None else np.asarray(style_points, float)
    timings["landmarks_s"] = time.perf_counter() - t0
    if max(content.shape[0] * content.shape[1], style.shape[0] * style.shape[1]) > NATIVE_MAX_PIXELS:
        kwargs = dict(method=method, preset=preset, seed=seed, device=device, progress=progress, save_every=save_every,
                      content_source=content_source, style_source=style_source, max_memory=max_memory,
                      **({} if texture_net is None else {"texture_net": texture_net}), **options)
        out, info = _transfer_reduced(content, style, cp, sp, params, init, callback, kwargs,
                                      content_owned=_content_owned)
        info["timings"]["landmarks_s"] += timings["landmarks_s"]
        info["timings"]["total_s"] = time.perf_counter() - t_start
        return out, info

    # working region
    H, W = content.shape[:2]
    box = face_crop_box(cp, content.shape) if params.crop == "face" else (0, 0, W, H)
    region = content[box[1]:box[3], box[0]:box[2]]
    rh, rw = region.shape[:2]
    wh = working_shape(rh, rw, params.size)
    if params.size < params.min_size((rh, rw)):  # an elongated region: its short side is too small
        need = params.min_size((rh, rw))
        raise BadInputError(f"the {'face' if params.crop == 'face' else 'image'} region of {rw}x{rh} px is "
                            f"{wh[1]}x{wh[0]} px at size {params.size}, too narrow for {params.patch_size}-px "
                            "MRF patches at the coarsest level: "
                            + (f"use --size {need} or more" if need <= 4096 else "crop it less elongated"),
                            path=content_source)
    scale_xy = (wh[1] / rw, wh[0] / rh)
    content_w = _resize(region, (wh[1], wh[0]))
    cpr = cp - [box[0], box[1]]
    cpw = _map_points(cp, box, scale_xy)
    warn = []
    if max(rh, rw) < params.size:
        warn.append(f"content {'face' if params.crop == 'face' else 'image'} region is "
                    f"{rw}x{rh} px: upscaled to {wh[1]}x{wh[0]} (pass a smaller --size)")
    sbox = face_crop_box(sp, style.shape) if params.crop == "face" else (0, 0, style.shape[1], style.shape[0])
    if max(sbox[2] - sbox[0], sbox[3] - sbox[1]) < params.size:
        warn.append(f"style {'face' if params.crop == 'face' else 'image'} region is "
                    f"{sbox[2] - sbox[0]}x{sbox[3] - sbox[1]} px, smaller than the working size {params.size} px: "
                    "its texture is upscaled")
    for w_ in warn:
        warnings.warn(w_, stacklevel=2)

    budget = default_max_memory() if max_memory is None else int(max_memory)
    need = estimate_transfer_memory(params, wh)
    if need > budget:
        raise MemoryBudgetError(f"this transfer needs about {need / 2**30:.1f} GiB at {wh[1]}x{wh[0]} px, over the "
                                f"{budget / 2**30:.1f} GiB budget: use a smaller --size or raise --max-memory")

    # style pre-warp onto the content region's geometry, at the region's own resolution (Sec. 2.3)
    t0 = time.perf_counter()
    from ..geometry.masks import face_mask, face_width, prior_mask
    from ..geometry.morph import remap

    folds, style_map = 0, None
    if params.align:
        from ..geometry.style_align import align_style_to_content

        al = align_style_to_content(style, region, style_points=sp, content_points=cpr, method=params.align,
                                    refine=params.align_refine, frame=params.align_frame, interpolation="lanczos")
        style_native, style_map, folds = al.image, al.map_xy, al.folds
    else:
        sreg = style[sbox[1]:sbox[3], sbox[0]:sbox[2]]
        style_native = _resize(sreg, (rw, rh))
    style_native = np.clip(style_native, 0, 1).astype(np.float32)
    style_w = _resize(style_native, (wh[1], wh[0]))
    timings["align_s"] = time.perf_counter() - t0

    # masks: skin of both faces (content region frame), facial prior, face region
    t0 = time.perf_counter()
    needs_skin = params.constraint == "skin" or params.style_region == "skin" or params.target_region == "skin" \
        or params.detail or params.keep_shading or params.marks != "off"
    skin_c = skin_s = None
    if needs_skin:
        from ..geometry.segment import skin_mask

        skin_c = skin_mask(content, cp, mesh=_face_mesh(content, cp))[box[1]:box[3], box[0]:box[2]]
        # the style lends texture only from bare skin: no hair, beard or highlights (issue 22)
        skin_style_own = skin_mask(style, sp, mesh=_face_mesh(style, sp), source=True)
        if style_map is not None:
            skin_s = remap(skin_style_own, style_map, border="constant")
        else:
            skin_s = _resize(np.repeat(skin_style_own[sbox[1]:sbox[3], sbox[0]:sbox[2], None], 3, 2), (rw, rh))[..., 0]
        skin_s = np.clip(skin_s, 0, 1).astype(np.float32)
    down = lambda m: None if m is None else cv2.resize(m, (wh[1], wh[0]), interpolation=cv2.INTER_AREA)  # noqa: E731
    skin_cw, skin_sw = down(skin_c), down(skin_s)
    face = face_mask(cpw, wh)
    prior = prior_mask(cpw, wh) if params.prior else None
    style_mask = {"skin": None if skin_sw is None else skin_sw * (skin_cw > 0.05), "face": face,
                  "image": None}[params.style_region]
    target_mask = None
    if params.target_region == "skin":
        target_mask = skin_cw
    elif params.target_region == "face":  # every patch that can change: the face grown by the features' reach
        r = max(1, int(round(0.05 * max(wh))))
        target_mask = cv2.dilate((face > 0.01).astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8))
        target_mask = target_mask.astype(np.float32)
    change_mask = None
    if params.constraint == "skin":
        cm = torch.from_numpy(np.ascontiguousarray(skin_cw))[None, None].to(device)
        change_mask = lambda shape: _resize_level(cm, shape)  # noqa: E731
    timings["masks_s"] = time.perf_counter() - t0

    # optimisation (Eq. 5 / 6 / 7), multi-resolution L-BFGS
    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)
    start = None
    if isinstance(init, str) and init == "random":
        start = np.random.default_rng(seed).uniform(0.0, 1.0, content_w.shape).astype(np.float32)
    elif not (isinstance(init, str) and init == "content"):
        start = _resize(_init_image(init, content)[box[1]:box[3], box[0]:box[2]], (wh[1], wh[0]))
    builder = _LossBuilder(params, content_w, style_w, prior, style_mask, target_mask, cpw, device)
    user_callback = callback
    if user_callback is not None:
        def callback(image, level, evaluation):  # noqa: F811 — adds the full-size picture of the step
            full = _paste(content, region, box, content_w, _resize(image, (wh[1], wh[0])), skin_c, params)
            user_callback(image=image, level=level, evaluation=evaluation, full_image=full, box=box)
    out_w, info = optimize_image(content_w, builder, levels=params.levels, iters=params.iters,
                                 lbfgs_history=params.lbfgs_history, line_search=params.line_search,
                                 seed=seed, device=device, progress=progress, callback=callback,
                                 save_every=save_every, level_init=params.level_init, change_mask=change_mask,
                                 start=start, eval_budget=params.eval_budget, converge=params.converge)
    timings["optimize_s"] = info["seconds"]

    # back to the region's full resolution: paste the *change*, so the content's own detail
    # above the working resolution survives instead of being blurred by the resampling
    t0 = time.perf_counter()
    out_region = _paste_region(region, content_w, out_w, skin_c, params)
    optimised_region = out_region
    detail_info = None
    if params.detail:
        from .detail import DetailParams, transfer_skin_detail

        dparams = DetailParams(strength=params.detail_strength)
        energies = None
        if style_map is not None:
            energies = _crop_map_energies(style, style_map, face_width(sp), dparams)
        from ..geometry.segment import beard_zone_mask

        # the content's upper lip and chin keep their own fine detail: the style's pores
        # copied there read as stubble specks on a clean-shaven face (issue 22)
        out_region, detail_info = transfer_skin_detail(out_region, style_native, skin_c, skin_s,
                                                       style_energy=energies, face_width=face_width(cpr),
                                                       params=dparams, own_zone=beard_zone_mask(cpr, (rh, rw)),
                                                       own_detail=region, return_info=True)
    timings["detail_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    marks_info = None
    if params.marks != "off":
        from .marks import transfer_marks

        out_region, found = transfer_marks(out_region, region, style_native, skin_c, skin_s, mode=params.marks,
                                           face_width=face_width(cpr), return_info=True)
        marks_info = {"mode": params.marks, "content": int(len(found["content"])), "style": int(len(found["style"]))}
    if params.keep_shading:
        from .colour import eye_distance, keep_content_shading

        ed = eye_distance(cpr)
        out_region = keep_content_shading(out_region, region, skin_c, params.shading_sigma * ed,
                                          colour_sigma=params.colour_sigma * ed)
    timings["finish_s"] = time.perf_counter() - t0
    out = _compose(content, region, box, out_region, params)
    timings["total_s"] = time.perf_counter() - t_start
    info = {
        "method": params.method, "preset": params.preset, "params": _jsonable(asdict(params)),
        "seed": seed, "device": str(device), "init": init if isinstance(init, str) else "image",
        "timings": timings, "levels": info["levels"],
        "optimizer": {k: info[k] for k in ("optimizer", "line_search", "lbfgs_history", "clamp")},
        "region_box": list(map(int, box)), "working_shape": list(wh), "warnings": warn,
        "prewarp_folds": int(folds), "detail": detail_info, "marks": marks_info,
        "memory_estimate_bytes": need, "versions": _versions(__version__),
        "images": {"content_w": content_w, "style_w": style_w, "output_w": out_w, "prior": prior, "face": face,
                   "region": region, "style_native": style_native, "skin_content": skin_c, "skin_style": skin_s,
                   "optimised_region": optimised_region, "output_region": out_region},
    }
    return out.astype(np.float32), info


def _jsonable(d):
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}


def _versions(version: str) -> dict:
    import platform

    return {"facetex": version, "torch": torch.__version__, "numpy": np.__version__, "opencv": cv2.__version__,
            "python": platform.python_version()}


def transfer(content, style, *, method: str = "facetex", **options) -> np.ndarray:
    """:func:`transfer_with_info` returning only the output image (H, W, 3) float32."""
    return transfer_with_info(content, style, method=method, **options)[0]
