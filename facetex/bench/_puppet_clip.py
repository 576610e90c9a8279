"""One run of ``facetex bench puppet`` (:mod:`facetex.bench.puppet`): a persona driven by one clip,
rendered in both modes and measured frame by frame; the partly-outside-the-frame check."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import BadInputError
from ._common import (
    image_grid,
)
from .puppet_measures import (
    ALPHA_PUPPET,
    ID_PHOTOS,
    ID_STEP,
    ID_THRESHOLD,
    PARTIAL_OUTSIDE,
    _series_measures,
    cheek_delta_e,
    cheek_mask,
    eye_aspect_ratio,
    eye_mask,
    face_skin_mask,
    lightness_difference,
    rest_lift_difference,
    sharpness_ratio,
    sheet_frames,
    under_eye_mask,
)

__all__ = [
    "shifted_clip",
]


def _collection_descriptor(persona_file, limit: int = ID_PHOTOS) -> np.ndarray:
    """Mean dlib descriptor of (up to ``limit`` evenly spaced) photos of a persona's source
    folder, read from its header only (no texture array is loaded)."""
    from ..io import read_image
    from ..landmarks import detect_faces
    from ..nets.dlib_resnet import face_descriptor
    from ..persona._persona_file import _read_header

    header, _, photos = _read_header(Path(persona_file))
    source = Path(header.get("source", ""))
    names = photos[:: max(1, math.ceil(len(photos) / limit))]
    ds = []
    for n in names:
        if not (source / n).is_file():
            continue
        img = read_image(source / n)
        faces = detect_faces(img, upsample=None)
        if faces:
            ds.append(face_descriptor(img, faces[0].points68))
    if not ds:
        raise BadInputError("no face found in the puppet's photos for the identity reference (its photo folder "
                            "moved?)", path=source)
    return np.mean(ds, axis=0)


#: Frames are upscaled (bicubic) to at least this longer side before measuring landmarks: dlib's
#: 68-point predictor is much noisier on GRID's ~100 px faces (driver and puppet alike).
MEASURE_SIDE = 720
#: Version of the landmark reading (:func:`_frame_measures`) in the driver cache's name: a cache of
#: an earlier reading is not used
MEASURE_VERSION = 2


def _frame_measures(image: np.ndarray, *, descriptor: bool = True):
    """(points68 or None, descriptor or None) of the largest face of a frame; landmarks in the
    frame's pixels, measured on a copy upscaled to MEASURE_SIDE."""
    import cv2

    from ..landmarks import detect_faces
    from ..nets.dlib_resnet import face_descriptor
    from .._landmark_fit import jittered_landmarks

    k = max(1.0, MEASURE_SIDE / max(image.shape[:2]))
    big = np.clip(cv2.resize(image, None, fx=k, fy=k, interpolation=cv2.INTER_CUBIC) if k > 1 else image, 0, 1)
    faces = detect_faces(big, upsample=0)
    if not faces:
        return None, None
    # the median of 14 fits (jittered boxes, mirrored): one fit read a still closed mouth 0.005 and
    # 0.051 open on two frames; a dark frame's mouth is read at a normalised exposure, as the tracker
    # reads it: read plainly, a dim copy of GRID lbax4n opened 0.53 as far as the clip itself
    p = jittered_landmarks(big, faces[0].box)
    return (p + 0.5) / k - 0.5, (face_descriptor(image, (p + 0.5) / k - 0.5) if descriptor else None)


def _flicker(frames: list[np.ndarray], alphas: list[np.ndarray], still: np.ndarray) -> float:
    """Mean |I_t − I_{t−1}| (0-255) inside both frames' face masks, over the 'still' frames t."""
    vals = []
    for t in np.flatnonzero(still):
        if t == 0:
            continue
        m = (alphas[t] > 0.5) & (alphas[t - 1] > 0.5)
        if m.sum() < 10:
            continue
        vals.append(255.0 * float(np.abs(frames[t] - frames[t - 1])[m].mean()))
    return float(np.mean(vals)) if vals else float("nan")


def _crop_box(points68: np.ndarray, shape, pad: float = 0.35):
    lo, hi = points68.min(axis=0), points68.max(axis=0)
    c, half = (lo + hi) / 2, (1 + 2 * pad) * max(hi - lo) / 2
    y0, x0 = int(max(0, c[1] - half)), int(max(0, c[0] - half))
    return y0, min(shape[0], int(c[1] + half)), x0, min(shape[1], int(c[0] + half))


def _zoom_regions(p68: np.ndarray, shape) -> dict:
    """Named (y0, y1, x0, x1) boxes around the mouth, the jaw edge, the hairline and a cheek."""
    iod = float(np.linalg.norm(p68[36] - p68[45]))
    r = max(8, int(round(0.4 * iod)))

    def box(c):
        y, x = int(round(c[1])), int(round(c[0]))
        return max(0, y - r), min(shape[0], y + r), max(0, x - r), min(shape[1], x + r)

    brow_top = p68[17:27, 1].min()
    return {
        "mouth": box(p68[48:68].mean(axis=0)),
        "jaw": box(p68[4]),
        "hairline": box([p68[27, 0], brow_top - 0.55 * iod]),
        "cheek": box((p68[1] + p68[31] + p68[41]) / 3),
    }


def _face_region_mask(persona):
    """bool (H, W) mouth region of the persona's texture: the outer lips dilated by 0.15 of the eye distance."""
    import cv2

    from ..geometry.masks import disc, polygon_mask

    p = persona.points68.mean(axis=0)
    W, H = persona.size
    m = polygon_mask(p[48:60], (H, W)) > 0.5
    k = max(1, int(round(0.15 * np.linalg.norm(p[36] - p[45]))))
    return cv2.dilate(m.astype(np.uint8), disc(k)) > 0


def _driver_measures(clip: Path, ours: list, found: np.ndarray, p68: np.ndarray, cache: Path | None) -> dict:
    """The driver's side (the same for every persona, cached per clip, size and frame count):
    re-detected landmarks (n, 68, 2) (NaN where not found) and the mean descriptor of every
    5th tracked frame."""
    from ..nets.dlib_resnet import face_descriptor

    n = len(ours)
    if cache is not None and cache.is_file():
        with np.load(cache) as z:
            if z["points"].shape[0] == n:
                return {"points": z["points"], "ref": z["ref"] if z["ref"].size else None}
    pts = np.full((n, 68, 2), np.nan)
    for r in ours:
        i = r["index"]
        if found[i]:
            q, _ = _frame_measures(r["driver"], descriptor=False)
            if q is not None:
                pts[i] = q
    desc = [face_descriptor(r["driver"], p68[r["index"]]) for r in ours[::5] if found[r["index"]]]
    ref = np.mean(desc, axis=0) if desc else None
    if cache is not None:
        from ..io import atomic_path

        cache.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(cache) as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, points=pts, ref=np.zeros(0) if ref is None else ref)
    return {"points": pts, "ref": ref}


def _median(a) -> float:
    a = np.asarray(a, float)
    return float(np.nanmedian(a)) if np.isfinite(a).any() else float("nan")


def _evaluate_clip(clip: Path, persona, ref_desc, out: Path, *, size, max_frames, params, write_media: bool,
                   progress: Callable | None, name: str = "", cache: Path | None = None) -> dict:
    """One run: ``persona`` driven by ``clip``; its row of measures (module docstring) and media."""
    from ..io import write_image, write_video
    from ..puppet import neutral_texture, prepare_puppetry, render_frames
    from ..puppet.composite import boundary_color_step
    from ..puppet.driver import mouth_opening

    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    session = prepare_puppetry(clip, persona, max_frames=max_frames, params=params)
    t_prep = time.perf_counter() - t0
    t0 = time.perf_counter()
    ours = list(render_frames(session, size=size, mode="composite", keep=True))
    t_render = time.perf_counter() - t0
    n = len(ours)
    track, pup = session.track, session.puppeteer
    scale = ours[0]["puppet"].shape[1] / track.frame_size[0]
    found = track.found[:n]
    p68 = (session.motion.points68 + 0.5) * scale - 0.5  # the driver's tracked landmarks, panel px
    iod = np.linalg.norm(p68[:, 36] - p68[:, 45], axis=1)
    drv = _driver_measures(clip, ours, found, p68, cache)
    drv_pts, drv_ref = drv["points"], drv["ref"]
    drv_open, drv_ear = mouth_opening(drv_pts), eye_aspect_ratio(drv_pts)
    speed = np.r_[np.nan, np.linalg.norm(np.diff(p68, axis=0), axis=2).mean(axis=1) / iod[1:]]
    speed[~found] = np.nan
    speed[1:][~found[:-1]] = np.nan
    still = np.isfinite(speed) & (speed <= np.nanpercentile(speed, 33)) if np.isfinite(speed).any() else \
        np.zeros(n, bool)
    id_frames = set(np.flatnonzero(found)[::ID_STEP].tolist())
    pup_pts = np.full((n, 68, 2), np.nan)
    d_pup, d_drv = np.full(n, np.nan), np.full(n, np.nan)
    step_c, step_d = np.full(n, np.nan), np.full(n, np.nan)
    de, sharp, eye_sharp = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    sharp_half = np.full(n, np.nan)
    under_eye = np.full(n, np.nan)
    for r in ours:
        i = r["index"]
        if r["lost"]:
            continue
        pts, desc = _frame_measures(r["puppet"], descriptor=i in id_frames)
        if pts is not None:
            pup_pts[i] = pts
            if desc is not None:
                d_pup[i] = np.linalg.norm(desc - ref_desc)
                if drv_ref is not None:
                    d_drv[i] = np.linalg.norm(desc - drv_ref)
        shown = r["alpha"] > ALPHA_PUPPET
        shape = r["puppet"].shape
        de[i] = cheek_delta_e(r["puppet"], r["driver"], cheek_mask(p68[i], shape) & shown)
        under_eye[i] = lightness_difference(r["puppet"], r["driver"], under_eye_mask(p68[i], shape) & shown)
        skin = face_skin_mask(p68[i], shape) & shown
        sharp[i] = sharpness_ratio(r["puppet"], r["driver"], skin)
        sharp_half[i] = sharpness_ratio(r["puppet"], r["driver"], skin, scale=0.5)
        eye_sharp[i] = sharpness_ratio(r["puppet"], r["driver"], eye_mask(p68[i], shape) & shown)
        mask = r["alpha"] > 0.5
        if mask.sum() > 16:
            band = max(2.0, 0.05 * iod[i])
            step_c[i] = boundary_color_step(r["puppet"], mask, band=band)[0]
            step_d[i] = boundary_color_step(r["driver"], mask, band=band)[0]
        if progress:
            progress(n=1, clip=clip.stem)
    pup_open, pup_ear = mouth_opening(pup_pts), eye_aspect_ratio(pup_pts)
    # "doing nothing": the same mask and feather, no lighting/colour transfer, no Poisson blending
    from dataclasses import replace

    saved = pup.params
    pasted = replace(saved, composite=replace(saved.composite, lighting="none", poisson=False))
    paste_c, paste_d = [], []
    try:
        pup.params = pasted
        for r in ours[::5]:
            if r["lost"]:
                continue
            i = r["index"]
            img, alpha = pup.render(i, r["grid"], r["texture"], r["driver"], scale)
            mask = alpha > 0.5
            if mask.sum() > 16:
                band = max(2.0, 0.05 * iod[i])
                paste_c.append(boundary_color_step(img, mask, band=band)[0])
                paste_d.append(boundary_color_step(r["driver"], mask, band=band)[0])
    finally:
        pup.params = saved
    # expression texture against the static average, mouth region, open-mouth frames
    static = neutral_texture(persona, persona.mean_fiducials, method="static", params=params.texture_params())
    mouth = _face_region_mask(persona)
    ok = np.isfinite(drv_open)
    open_frames = np.flatnonzero(ok & (drv_open >= np.nanpercentile(drv_open, 75))) if ok.any() else []
    tex_open = float(np.mean([255 * np.abs(ours[i]["texture"] - static)[mouth].mean() for i in open_frames])) \
        if len(open_frames) else float("nan")
    sampled = np.array(sorted(id_frames), int)
    closer = (np.nan_to_num(d_pup[sampled], nan=9.0) < np.nan_to_num(d_drv[sampled], nan=0.0)) if sampled.size \
        else np.zeros(0, bool)
    row = {
        "run": f"{name}/{clip.stem}" if name else clip.stem,
        "persona": name,
        "clip": clip.stem,
        "frames": n,
        "lost": int((~found).sum()),
        "lost_causes": track.lost_causes,
        "driver_glasses": pup.glasses,  # kept in front of the puppet
        "cheek_de": _median(de),
        "under_eye_dl": _median(under_eye),
        "sharp": _median(sharp),
        "sharp_half": _median(sharp_half),
        "eye_sharp": _median(eye_sharp),
        "id_closer": float(closer.mean()) if closer.size else float("nan"),
        "mouth_detected": float(np.isfinite(pup_open[found]).mean()) if found.any() else float("nan"),
        "step_ratio": float(np.nanmean(step_c) / np.nanmean(step_d)) if np.isfinite(step_d).any() else float("nan"),
        "step_puppet": float(np.nanmean(step_c)) if np.isfinite(step_c).any() else float("nan"),
        "step_driver": float(np.nanmean(step_d)) if np.isfinite(step_d).any() else float("nan"),
        "step_ratio_paste": float(np.nanmean(paste_c) / np.nanmean(paste_d)) if paste_d else float("nan"),
        "tex_open": tex_open,
        "rest_lift": rest_lift_difference(drv_pts, pup_pts, drv_open),
        "id_puppet": float(np.nanmean(d_pup)) if np.isfinite(d_pup).any() else float("nan"),
        "id_frac": float(np.mean(np.nan_to_num(d_pup[sampled], nan=9.0) < ID_THRESHOLD)) if sampled.size
        else 0.0,
        "id_driver": float(np.nanmean(d_drv)) if np.isfinite(d_drv).any() else float("nan"),
        "id_frames": int(sampled.size),
        "flicker": _flicker([r["puppet"] for r in ours], [r["alpha"] for r in ours], still),
        "fps": n / t_render,
        "prepare_s": t_prep,
        "still_frames": int(still.sum()),
        "timings": dict(session.timings),
        "driver_opening": drv_open.tolist(),
        "puppet_opening": pup_open.tolist(),
        "driver_ear": drv_ear.tolist(),
        "puppet_ear": pup_ear.tolist(),
        "cheek_de_frames": de.tolist(),
        "sharp_frames": sharp.tolist(),
        "shape": pup.shape_source,
    }
    _series_measures(row)
    media = {}
    # contact sheet: 8 frames evenly spaced, with the most closed, widest-open and middle mouth frames
    three = sheet_frames(np.where(found, drv_open, np.nan))
    idx = np.unique(np.r_[np.linspace(0, n - 1, 8 - 3).round().astype(int), three])
    faces = {}
    for i in idx:
        r = ours[i]
        faces[i] = r["driver"] * 0 + np.asarray(pup.params.plain, np.float32) if r["lost"] else \
            pup.render(i, r["grid"], r["texture"], r["driver"], scale, "face")[0]
    if found.any():
        y0, y1, x0, x1 = _crop_box(np.nanmean(p68[found], axis=0), ours[0]["puppet"].shape)
    else:
        y0, y1, x0, x1 = 0, ours[0]["puppet"].shape[0], 0, ours[0]["puppet"].shape[1]
    rows = [[ours[i]["driver"][y0:y1, x0:x1] for i in idx], [ours[i]["puppet"][y0:y1, x0:x1] for i in idx],
            [faces[i][y0:y1, x0:x1] for i in idx]]
    labels = [[f"#{i} open {drv_open[i]:.2f}" if np.isfinite(drv_open[i]) else f"#{i}" for i in idx],
              [("LOST" if ours[i]["lost"] else f"open {pup_open[i]:.2f}" if np.isfinite(pup_open[i]) else "no face")
               for i in idx],
              ["face mode" if k == 0 else None for k in range(len(idx))]]
    sheet = out / f"{clip.stem}_contact_sheet.png"
    write_image(sheet, image_grid(rows, cell=200, cell_labels=labels, col_titles=[f"frame {i}" for i in idx]),
                overwrite=True)
    full = np.concatenate([np.concatenate([ours[i]["driver"], ours[i]["puppet"], faces[i]], axis=1) for i in idx], 0)
    sheet100 = out / f"{clip.stem}_sheet_100.png"
    write_image(sheet100, full, overwrite=True)
    # closed | widest | middle, each row driver | composite | face mode, at 100 %
    sheet3 = out / f"{clip.stem}_sheet3_100.png"
    write_image(sheet3, np.concatenate([np.concatenate([ours[i]["driver"], ours[i]["puppet"], faces[i]], axis=1)
                                        for i in three], 0), overwrite=True)
    row["sheet_frames"] = [int(i) for i in three]
    media.update(contact_sheet=str(sheet), sheet_100=str(sheet100), sheet3_100=str(sheet3))
    j = three[1]
    if ok.any() and found[j]:
        import cv2

        tiles = []
        for reg, (a, b, c, d) in _zoom_regions(p68[j], ours[j]["puppet"].shape).items():
            pair = np.concatenate([ours[j]["driver"][a:b, c:d], ours[j]["puppet"][a:b, c:d]], axis=1)
            tiles.append(cv2.resize(pair, None, fx=4, fy=4, interpolation=cv2.INTER_NEAREST))
        hmax = max(t.shape[0] for t in tiles)
        tiles = [np.pad(t, ((0, hmax - t.shape[0]), (0, 4), (0, 0)), constant_values=1.0) for t in tiles]
        zoom = out / f"{clip.stem}_zoom_frame{j}.png"
        write_image(zoom, np.concatenate(tiles, axis=1), overwrite=True)
        media["zoom"] = str(zoom)
    if write_media:
        mp4 = out / f"{clip.stem}_side_by_side.mp4"
        write_video(mp4, (np.concatenate([r["driver"], r["puppet"]], axis=1) for r in ours), track.fps,
                    audio_from=clip if track.has_audio else None, overwrite=True)
        media["mp4"] = str(mp4)
    row["media"] = media
    return row


def shifted_clip(src, dst, *, start: float = 1 / 3, end: float = 2 / 3, shift: float = 0.5,
                 max_frames: int | None = None) -> np.ndarray:
    """Write ``dst``: the clip ``src`` slid sideways out of its frame (by 0 up to the frame ``start``
    fraction, growing linearly to ``shift`` x the width at ``end``, held after it; the frame's
    edge column fills the uncovered part). Returns the per-frame shift in px (negative: left)."""
    import cv2

    from ..io import iter_video_frames, video_info, write_video

    info = video_info(src)
    frames = list(iter_video_frames(src, max_frames=max_frames))
    n = len(frames)
    h, w = frames[0].shape[:2]
    t = np.clip((np.arange(n) / max(n - 1, 1) - start) / max(end - start, 1e-9), 0, 1)
    dx = -t * shift * w
    out = [cv2.warpAffine(f, np.float32([[1, 0, d], [0, 1, 0]]), (w, h), borderMode=cv2.BORDER_REPLICATE)
           for f, d in zip(frames, dx)]
    write_video(dst, out, info["fps"] or 25.0, overwrite=True)
    return dx


def _partial_check(clip: Path, out: Path, max_frames) -> dict:
    """Rejection of half-out-of-frame faces: the clip slid out of its frame (:func:`shifted_clip`);
    ground truth from the unshifted clip's landmarks moved with the frame."""
    from ..puppet.driver import track_driver

    ref = track_driver(clip, max_frames=max_frames)
    moved = out / f"partial_{clip.stem}.mp4"
    dx = shifted_clip(clip, moved, max_frames=max_frames)
    tr = track_driver(moved, max_frames=max_frames)
    W = ref.frame_size[0]
    n = min(len(dx), tr.n_frames, ref.n_frames)
    outside = np.full(n, np.nan)
    for i in range(n):
        if ref.found[i]:
            x = ref.points68[i, :, 0] + dx[i]
            lo, hi = x.min(), x.max()
            outside[i] = (max(0.0, -0.5 - lo) + max(0.0, hi - (W - 0.5))) / max(hi - lo, 1e-9)
    partial = np.isfinite(outside) & (outside >= PARTIAL_OUTSIDE)
    whole = np.isfinite(outside) & (outside == 0)
    return {
        "clip": moved.name,
        "partial_frames": int(partial.sum()),
        "partial_rejected": int((partial & ~tr.found[:n]).sum()),
        "whole_frames": int(whole.sum()),
        "whole_kept": int((whole & tr.found[:n]).sum()),
        "lost_causes": tr.lost_causes,
    }


