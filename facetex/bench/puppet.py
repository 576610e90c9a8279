"""``facetex bench puppet``: persona puppetry driven by talking-face clips (Tom Hanks §4, §6).

The paper has no quantitative puppetry benchmark ("Evaluating a puppetry system objectively
is extremely hard"); we measure what a viewer of the composited videos sees:

* **mouth**: the rendered puppet's mouth opening (inner-lip gap / outer-eye-corner distance,
  dlib landmarks re-detected on the output frames) against the driver's (the same measure on
  the driver frames; both on frames upscaled to 720 px, dlib's predictor is noisy on ~100 px
  faces): least-squares **slope** of puppet on driver (target >= 0.8: the puppet opens as far
  as the driver) and Pearson **correlation** (target >= 0.85);
* **boundary colour step**: CIE76 ΔE between bands just inside and just outside the edge of
  the composite mask (alpha 0.5), per angular sector, averaged; divided by the driver's own
  step at the same place in its original frame (target <= 2: the edge is not more visible
  than the skin, hair and background edges the driver's own face has there). The same ratio
  for the puppet pasted with the same mask but without colour/lighting transfer and Poisson
  blending ("pasted", every 5th frame) shows what the measure does when the colour is off;
* **expression texture**: mean |texture − static average texture| (0-255) in the mouth region
  of the texture, on the frames where the driver's mouth is open (top quarter of the opening);
* **identity**: dlib FaceRecognitionNet distance of every rendered frame to the mean
  descriptor of the puppet's photo collection (< 0.6 on >= 90 % of frames), and to the
  driver's mean descriptor (should be larger);
* **lost frames**: frames where the driver's face was not found or was rejected (partly
  outside the frame, implausible), and a **partial-face check**: the first clip shifted so that
  its face leaves the frame sideways; every frame with >= 10 % of the face box outside must be
  rejected, every frame with the face whole inside kept;
* **temporal stability**: mean absolute frame-to-frame change (0-255) of the composited face in
  frames where the driver's face barely moves.

Outputs per clip: a contact sheet of 8 frames (driver, composite, puppet face alone) scaled to
fit cells, the same frames at 100 % (``*_sheet_100.png``), zoomed crops of the most open-mouth
frame (mouth, jaw edge, hairline, cheek; driver | composite, 4x nearest) and, for the first
clip, a side-by-side MP4.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..errors import BadInputError
from ._common import Column, check_out_dir, csv_table, image_grid, json_safe, markdown_table, versions, write_text

__all__ = ["register_bench", "run_bench_puppet", "mouth_slope", "shifted_clip"]

ID_THRESHOLD = 0.6
SLOPE_TARGET = 0.8
CORR_TARGET = 0.85
STEP_RATIO_TARGET = 2.0
ID_FRACTION_TARGET = 0.9
PARTIAL_OUTSIDE = 0.1  # a frame is "partial" when this fraction of the face box is outside the frame

COLUMNS = (
    Column("clip", "driver clip"),
    Column("frames", "frames", "d"),
    Column("lost", "lost", "d"),
    Column("mouth_slope", "mouth slope", ".2f"),
    Column("mouth_r", "mouth r", ".3f"),
    Column("mouth_detected", "puppet detected", ".0%"),
    Column("step_ratio", "edge ΔE ratio", ".2f"),
    Column("step_puppet", "edge ΔE", ".1f"),
    Column("step_driver", "driver's ΔE", ".1f"),
    Column("step_ratio_paste", "edge ratio, pasted", ".2f"),
    Column("tex_open", "tex-static open (0-255)", ".1f"),
    Column("id_puppet", "id dist puppet", ".3f"),
    Column("id_frac", "frames < 0.6", ".0%"),
    Column("id_driver", "id dist driver", ".3f"),
    Column("flicker", "flicker", ".2f"),
    Column("fps", "render fps", ".1f"),
)


def _pearson(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 3 or a[ok].std() == 0 or b[ok].std() == 0:
        return float("nan")
    return float(np.corrcoef(a[ok], b[ok])[0, 1])


def mouth_slope(driver, puppet) -> float:
    """Least-squares slope of ``puppet`` on ``driver`` (frames where both are finite): 1 when the
    puppet's mouth opens exactly as far as the driver's, 0 when it does not follow."""
    a, b = np.asarray(driver, float), np.asarray(puppet, float)
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 3 or a[ok].std() == 0:
        return float("nan")
    return float(np.polyfit(a[ok], b[ok], 1)[0])


def _collection_descriptor(persona, limit: int = 120) -> np.ndarray:
    """Mean dlib descriptor of (up to ``limit`` evenly spaced) photos of the persona's source folder."""
    from ..io import read_image
    from ..landmarks import detect_faces
    from ..nets.dlib_resnet import face_descriptor

    names = persona.photos[:: max(1, math.ceil(len(persona.photos) / limit))]
    ds = []
    for n in names:
        img = read_image(Path(persona.source) / n)
        faces = detect_faces(img, upsample=None)
        if faces:
            ds.append(face_descriptor(img, faces[0].points68))
    if not ds:
        raise BadInputError("no face found in the puppet's photos for the identity reference", path=persona.source)
    return np.mean(ds, axis=0)


#: Frames are upscaled (bicubic) to at least this longer side before measuring landmarks: dlib's
#: 68-point predictor is much noisier on GRID's ~100 px faces (driver and puppet alike).
MEASURE_SIDE = 720


def _frame_measures(image: np.ndarray, *, descriptor: bool = True):
    """(points68 or None, descriptor or None) of the largest face of a frame; landmarks in the
    frame's pixels, measured on a copy upscaled to MEASURE_SIDE."""
    import cv2

    from ..landmarks import detect_faces
    from ..nets.dlib_resnet import face_descriptor

    k = max(1.0, MEASURE_SIDE / max(image.shape[:2]))
    big = cv2.resize(image, None, fx=k, fy=k, interpolation=cv2.INTER_CUBIC) if k > 1 else image
    faces = detect_faces(np.clip(big, 0, 1), upsample=0)
    if not faces:
        return None, None
    p = faces[0].points68
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

    from ..persona.composite import polygon_mask

    p = persona.points68.mean(axis=0)
    W, H = persona.size
    m = polygon_mask(p[48:60], (H, W)) > 0.5
    k = max(1, int(round(0.15 * np.linalg.norm(p[36] - p[45]))))
    return cv2.dilate(m.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * k + 1,) * 2)) > 0


def _evaluate_clip(clip: Path, persona, ref_desc, out: Path, *, size, max_frames, params, write_media: bool,
                   progress: Callable | None) -> dict:
    from ..io import write_image, write_video
    from ..nets.dlib_resnet import face_descriptor
    from ..persona.composite import boundary_color_step
    from ..persona.driver import mouth_opening
    from ..persona.puppet import neutral_texture, prepare_puppetry, render_frames

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
    # driver signals: measured like the puppet's (lost frames excluded)
    drv_open = np.full(n, np.nan)
    for r in ours:
        if found[r["index"]]:
            pts, _ = _frame_measures(r["driver"], descriptor=False)
            drv_open[r["index"]] = mouth_opening(pts) if pts is not None else np.nan
    p68 = (session.motion.points68 + 0.5) * scale - 0.5
    iod = np.linalg.norm(p68[:, 36] - p68[:, 45], axis=1)
    speed = np.r_[np.nan, np.linalg.norm(np.diff(p68, axis=0), axis=2).mean(axis=1) / iod[1:]]
    speed[~found] = np.nan
    speed[1:][~found[:-1]] = np.nan
    still = np.isfinite(speed) & (speed <= np.nanpercentile(speed, 33)) if np.isfinite(speed).any() else \
        np.zeros(n, bool)
    drv_desc = [face_descriptor(r["driver"], p68[r["index"]]) for r in ours[::5] if found[r["index"]]]
    drv_ref = np.mean(drv_desc, axis=0) if drv_desc else None
    pup_open, d_pup, d_drv = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    step_c, step_d = np.full(n, np.nan), np.full(n, np.nan)
    for r in ours:
        i = r["index"]
        if r["lost"]:
            continue
        pts, desc = _frame_measures(r["puppet"])
        if pts is not None:
            pup_open[i] = mouth_opening(pts)
            d_pup[i] = np.linalg.norm(desc - ref_desc)
            if drv_ref is not None:
                d_drv[i] = np.linalg.norm(desc - drv_ref)
        mask = r["alpha"] > 0.5
        if mask.sum() > 16:
            band = max(2.0, 0.05 * iod[i])
            step_c[i] = boundary_color_step(r["puppet"], mask, band=band)[0]
            step_d[i] = boundary_color_step(r["driver"], mask, band=band)[0]
        if progress:
            progress(n=1, clip=clip.stem)
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
    row = {
        "clip": clip.stem,
        "frames": n,
        "lost": int((~found).sum()),
        "lost_causes": track.lost_causes,
        "mouth_slope": mouth_slope(drv_open, pup_open),
        "mouth_r": _pearson(drv_open, pup_open),
        "mouth_detected": float(np.isfinite(pup_open[found]).mean()) if found.any() else float("nan"),
        "step_ratio": float(np.nanmean(step_c) / np.nanmean(step_d)) if np.isfinite(step_d).any() else float("nan"),
        "step_puppet": float(np.nanmean(step_c)) if np.isfinite(step_c).any() else float("nan"),
        "step_driver": float(np.nanmean(step_d)) if np.isfinite(step_d).any() else float("nan"),
        "step_ratio_paste": float(np.nanmean(paste_c) / np.nanmean(paste_d)) if paste_d else float("nan"),
        "tex_open": tex_open,
        "id_puppet": float(np.nanmean(d_pup)) if np.isfinite(d_pup).any() else float("nan"),
        "id_frac": float(np.mean(np.nan_to_num(d_pup[found], nan=9.0) < ID_THRESHOLD)) if found.any() else 0.0,
        "id_driver": float(np.nanmean(d_drv)) if np.isfinite(d_drv).any() else float("nan"),
        "flicker": _flicker([r["puppet"] for r in ours], [r["alpha"] for r in ours], still),
        "fps": n / t_render,
        "prepare_s": t_prep,
        "still_frames": int(still.sum()),
        "timings": dict(session.timings),
        "driver_opening": drv_open.tolist(),
        "puppet_opening": pup_open.tolist(),
        "shape": pup.shape_source,
    }
    media = {}
    # contact sheet: 8 frames evenly spaced, the most open mouth among them
    idx = np.linspace(0, n - 1, 8).round().astype(int)
    if ok.any():
        j = int(np.nanargmax(np.where(ok, drv_open, -1)))
        idx[np.argmin(np.abs(idx - j))] = j
        idx = np.unique(idx)
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
    media.update(contact_sheet=str(sheet), sheet_100=str(sheet100))
    if ok.any() and found[j]:
        import cv2

        tiles = []
        for name, (a, b, c, d) in _zoom_regions(p68[j], ours[j]["puppet"].shape).items():
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
    from ..persona.driver import track_driver

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


def _load_or_build_persona(puppet, out: Path, progress):
    from ..persona import build_persona, load_persona

    p = Path(puppet)
    if p.is_file():
        return load_persona(p), str(p)
    cached = out / f"{p.name}.persona"
    if cached.is_file():
        persona = load_persona(cached)
        if Path(persona.source).resolve() == p.resolve():
            return persona, str(cached)
    persona = build_persona(p, jobs=1, progress=progress)
    persona.save(cached, overwrite=True)
    return persona, str(cached)


def _data_paths(data, drivers, puppet) -> tuple[Path, Path]:
    root = data or os.environ.get("FACETEX_DATA")
    if drivers is None or puppet is None:
        if not root:
            raise BadInputError("no data: give --data DIR (with grid/ and lfw/George_W_Bush/), set FACETEX_DATA, "
                                "or give --drivers and --puppet")
        root = Path(root)
        drivers = root / "grid" if drivers is None else drivers
        puppet = root / "lfw" / "George_W_Bush" if puppet is None else puppet
    return Path(drivers), Path(puppet)


_WORKER_CACHE: dict = {}  # persona file -> (persona, identity reference), per worker process


def _bench_item(p: dict):
    """One item of the benchmark in a worker (``engine``): a clip's evaluation or the partial-face
    check; the persona is loaded (and its identity reference computed) once per worker."""
    from ..persona import load_persona
    from ..persona.puppet import PuppetParams

    if p["kind"] == "partial":
        return _partial_check(Path(p["clip"]), Path(p["out"]), p["max_frames"])
    if p["persona_file"] not in _WORKER_CACHE:
        persona = load_persona(p["persona_file"])
        _WORKER_CACHE.clear()
        _WORKER_CACHE[p["persona_file"]] = (persona, _collection_descriptor(persona))
    persona, ref = _WORKER_CACHE[p["persona_file"]]
    return _evaluate_clip(Path(p["clip"]), persona, ref, Path(p["out"]), size=p["size"], max_frames=p["max_frames"],
                          params=PuppetParams(shape=p["shape"], weights=p["weights"],
                                              weight_smoothing=p["weight_smoothing"]),
                          write_media=p["write_media"],
                          progress=None)


def run_bench_puppet(drivers=None, puppet=None, out="bench_out/puppet", *, data=None, clips: int | None = None,
                     size: int | None = 256, max_frames: int | None = None, texture_shape: str = "collection",
                     weights: str = "regional", weight_smoothing: float | None = None, partial: bool = True,
                     progress: Callable | None = None, engine=None) -> dict:
    """Run the puppetry benchmark: every ``*.mpg`` / ``*.mp4`` in ``drivers`` (the first ``clips``)
    drives the persona ``puppet`` (a .persona file, or a photo folder built once and cached in
    ``out``); ``data`` (or FACETEX_DATA) supplies the defaults ``grid/`` and
    ``lfw/George_W_Bush``. Writes table.md, table.csv, results.json, per clip a contact sheet,
    a 100 % sheet and zoomed crops, and for the first clip a side-by-side MP4.
    ``engine`` (:mod:`facetex.batch.engines`, started): the clips (and the partial-face check)
    run as its items, in parallel; default: one after another in this process.
    Returns {"out", "rows", "summary", "partial", "files", "targets_met"}."""
    from dataclasses import replace

    from ..io import write_json
    from ..persona.puppet import PuppetParams

    drivers, puppet = _data_paths(data, drivers, puppet)
    if not drivers.exists():
        raise BadInputError("driver clips not found", path=drivers)
    files = sorted(f for f in drivers.iterdir() if f.suffix.lower() in (".mpg", ".mp4", ".mov", ".avi", ".mkv")) \
        if drivers.is_dir() else [drivers]
    if not files:
        raise BadInputError("no driver videos (.mpg/.mp4/.mov/.avi/.mkv) found", path=drivers)
    if clips is not None and clips < 1:
        raise BadInputError(f"--clips must be at least 1, got {clips}")
    files = files[: clips or None]
    out = check_out_dir(out)
    persona, persona_file = _load_or_build_persona(puppet, out, progress)
    ref = _collection_descriptor(persona)
    params = PuppetParams(shape=texture_shape, weights=weights)
    if weight_smoothing is not None:
        params = replace(params, weight_smoothing=float(weight_smoothing))
    params.texture_params()  # unknown weights, negative smoothing: an error before any work
    from ..batch.engines import InlineEngine

    if engine is None or isinstance(engine, InlineEngine):
        rows = []
        for k, clip in enumerate(files):
            rows.append(_evaluate_clip(clip, persona, ref, out, size=size, max_frames=max_frames, params=params,
                                       write_media=(k == 0), progress=progress))
        part = _partial_check(files[0], out, max_frames) if partial else None
    else:
        from ..batch import map_items

        items = [{"kind": "clip", "clip": str(c), "persona_file": str(Path(persona_file).resolve()),
                  "out": str(out.resolve()), "size": size, "max_frames": max_frames, "shape": texture_shape,
                  "weights": weights, "weight_smoothing": params.weight_smoothing,
                  "write_media": k == 0} for k, c in enumerate(files)]
        if partial:
            items.append({"kind": "partial", "clip": str(files[0]), "out": str(out.resolve()),
                          "max_frames": max_frames})

        def done(n=1, index=0, result=None):
            if progress and items[index]["kind"] == "clip":
                progress(n=int(result.get("frames", 1)), clip=Path(items[index]["clip"]).name)

        results = map_items(engine, _bench_item, items, progress=done)
        rows = results[: len(files)]
        part = results[len(files)] if partial else None
    summary = {"clip": "mean"}
    for c in COLUMNS[1:]:
        vals = [r[c.key] for r in rows if isinstance(r.get(c.key), (int, float)) and np.isfinite(r[c.key])]
        summary[c.key] = float(np.mean(vals)) if vals else float("nan")
    summary["frames"], summary["lost"] = int(sum(r["frames"] for r in rows)), int(sum(r["lost"] for r in rows))
    table_rows = rows + [summary]
    head = (f"# Puppetry benchmark\n\nPuppet: `{puppet}` ({len(persona)} photos); drivers: {len(files)} clip(s) "
            f"from `{drivers}`; panel size {size or 'native'}; puppet shape: {rows[0]['shape']}; texture "
            f"weights: {weights}; weight smoothing: {params.weight_smoothing:g} s.\n\n"
            f"Targets per clip: mouth slope >= {SLOPE_TARGET} and r >= {CORR_TARGET}; edge ΔE ratio (composite "
            f"/ driver's own) <= {STEP_RATIO_TARGET}; id dist to the puppet < {ID_THRESHOLD} on >= "
            f"{ID_FRACTION_TARGET:.0%} of frames and smaller than to the driver; partial faces rejected.\n\n")

    def each(key, test):
        return bool(rows) and all(np.isfinite(r[key]) and test(r[key]) for r in rows)

    ok = {
        "mouth": each("mouth_slope", lambda v: v >= SLOPE_TARGET) and each("mouth_r", lambda v: v >= CORR_TARGET),
        "boundary": each("step_ratio", lambda v: v <= STEP_RATIO_TARGET),
        "identity": each("id_frac", lambda v: v >= ID_FRACTION_TARGET)
        and all(r["id_puppet"] < r["id_driver"] for r in rows),
    }
    tail = "\n" + "; ".join(f"{k} target met: {v}" for k, v in ok.items()) + "\n"
    lost = {r["clip"]: r["lost_causes"] for r in rows if r["lost"]}
    if lost:
        tail += "\nLost frames by cause: " + "; ".join(f"{c}: {v}" for c, v in lost.items()) + "\n"
    if part is not None:
        ok["partial"] = (part["partial_rejected"] == part["partial_frames"]
                         and part["whole_kept"] == part["whole_frames"])
        tail += (f"\nPartial faces (`{part['clip']}`, the first clip slid out of its frame): "
                 f"{part['partial_rejected']}/{part['partial_frames']} frames with >= {PARTIAL_OUTSIDE:.0%} of the "
                 f"face outside rejected, {part['whole_kept']}/{part['whole_frames']} whole-face frames kept "
                 f"(causes: {part['lost_causes']}); target met: {ok['partial']}\n")
    paths = {"table_md": out / "table.md", "table_csv": out / "table.csv", "results": out / "results.json"}
    write_text(paths["table_md"], head + markdown_table(COLUMNS, table_rows) + tail)
    write_text(paths["table_csv"], csv_table(COLUMNS, table_rows))
    write_json(paths["results"], json_safe({"bench": "puppet", "settings": {"drivers": str(drivers), "puppet": str(puppet),
                                                         "persona_file": persona_file, "size": size,
                                                         "weights": weights,
                                                         "max_frames": max_frames, "versions": versions()},
                                            "rows": rows, "summary": summary, "partial": part,
                                            "targets_met": ok}), overwrite=True)
    if rows:
        paths.update({k: Path(v) for k, v in rows[0]["media"].items()})
    return {"out": out, "rows": rows, "summary": summary, "partial": part, "files": paths, "targets_met": ok}


# --------------------------------------------------------------------------- CLI
def register_bench(bench_subparsers) -> argparse.ArgumentParser:
    """Add the ``puppet`` sub-parser to ``facetex bench``."""
    from ..cli._common import bounded_int, finite_float, positive_int
    from ._common import add_bench_options

    p = bench_subparsers.add_parser(
        "puppet", help="puppetry: talking-face clips drive a persona (mouth, boundary colour, identity, lost faces)",
        description="Driver clips drive a persona (Tom Hanks §4, §6); measured per clip: the mouth (slope and "
                    "correlation of the puppet's opening on the driver's), the colour step at the composite's "
                    "edge relative to the driver's own, the expression texture, identity distances to the "
                    "puppet and to the driver, lost and rejected frames (with a half-out-of-frame check), and "
                    "flicker on still frames. Writes table.md/.csv, results.json, contact sheets (fitted and "
                    "at 100 %%), zoomed crops and, for the first clip, a side-by-side MP4.")
    add_bench_options(p, "puppet", "data root holding grid/ (driver clips) and lfw/George_W_Bush/ (the puppet)")
    p.add_argument("--drivers", metavar="DIR", help="folder of driver videos (default DATA/grid)")
    p.add_argument("--puppet", metavar="PATH", help="puppet .persona file or photo folder (default DATA/lfw/George_W_Bush)")
    p.add_argument("--clips", type=positive_int, help="use only the first N clips")
    p.add_argument("--size", type=bounded_int(32, 4096), default=256, help="longer side of the rendered frames (default 256)")
    p.add_argument("--max-frames", type=positive_int, help="use only the first N frames of each clip")
    p.add_argument("--shape", choices=("collection", "generic"), default="collection",
                   help="puppet average shape: photometric stereo (falls back to generic) or the generic face")
    p.add_argument("--weights", choices=("regional", "global"), default="regional",
                   help="expression weights of the puppet's texture: regional (default) or the paper's global")
    p.add_argument("--weight-smoothing", type=finite_float(0.0, 10.0), metavar="SECONDS",
                   help="temporal coherence of the regional weights (bilateral filter over this many seconds; "
                        "0 = per frame; default: the puppet's default)")
    p.add_argument("--no-partial", action="store_true", help="skip the half-out-of-frame check")
    from ..cli._common import add_engine_options

    add_engine_options(p, jobs_default=1, jobs_help="local: worker processes, one clip each (default 1: the clips "
                                                    "one after another in this process); ray: clips in flight")
    p.set_defaults(func=_run)
    return p



def _run(args) -> int:
    from ..cli._common import progress_bar
    from ..io import video_info
    from ._common import data_root, finish_bench

    root = None if (args.drivers and args.puppet and not args.data) else data_root(args.data)
    drivers, puppet = _data_paths(root, args.drivers, args.puppet)
    clips = sorted(f for f in drivers.iterdir() if f.suffix.lower() in (".mpg", ".mp4", ".mov", ".avi", ".mkv")) \
        if drivers.is_dir() else [drivers]
    clips = clips[: args.clips or None]
    total = 0
    for c in clips:  # the bar counts evaluated frames
        try:
            n = video_info(c)["n_frames"]
        except Exception:  # noqa: BLE001 - the run itself reports a bad clip
            n = 0
        total += min(n, args.max_frames) if args.max_frames else n
    from ..cli._common import engine_from_args

    with engine_from_args(args, inline_single=True) as engine, \
            progress_bar(total=total or None, desc="bench puppet", unit="frame", disable=args.quiet) as bar:
        res = run_bench_puppet(drivers, puppet, args.out, clips=args.clips, size=args.size,
                               max_frames=args.max_frames, texture_shape=args.shape, weights=args.weights,
                               weight_smoothing=args.weight_smoothing, partial=not args.no_partial,
                               progress=bar, engine=engine)
    table = Path(res["files"]["table_md"]).read_text(encoding="utf-8")
    finish_bench(args, "puppet", res["out"], res["files"], inputs={"drivers": drivers, "puppet": puppet},
                 settings={"drivers": str(drivers), "puppet": str(puppet)},
                 summary={"summary": res["summary"], "partial": res["partial"], "targets_met": res["targets_met"]},
                 table=table)
    return 0


def run_bench_puppet_cli(argv: Sequence[str] | None = None) -> int:
    """Stand-alone entry (``python -m facetex.bench.puppet``)."""
    ap = argparse.ArgumentParser(prog="facetex bench")
    register_bench(ap.add_subparsers(dest="bench", required=True))
    args = ap.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    raise SystemExit(run_bench_puppet_cli())
