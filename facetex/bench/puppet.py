"""``facetex bench puppet``: persona puppetry driven by GRID talking-face clips (Tom Hanks §4, §6).

The paper has no quantitative puppetry benchmark ("Evaluating a puppetry system objectively
is extremely hard"); we measure three properties of the rendered videos:

* **expression fidelity**: Pearson correlation over time between the driver's mouth opening
  (inner-lip gap / outer-eye-corner distance, dlib landmarks on the driver frames) and the
  rendered puppet's (landmarks re-detected on the rendered frames); target >= 0.8. Both are
  measured the same way, on frames upscaled to 720 px (dlib's predictor is noisy on ~100 px faces);
* **identity**: dlib FaceRecognitionNet distance of every rendered frame to the mean
  descriptor of the puppet's photo collection (< 0.6 on >= 90 % of frames), and to the
  driver's mean descriptor (should be larger);
* **temporal stability**: mean absolute frame-to-frame change (0-255 scale) of the rendered
  face in frames where the driver's face barely moves (landmark speed in the lowest third),
  for the expression-dependent texture and the ``static`` average texture.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..errors import BadInputError
from ._common import Column, check_out_dir, csv_table, image_grid, json_safe, markdown_table, versions, write_text

__all__ = ["register_bench", "run_bench_puppet", "DEFAULT_DRIVERS", "DEFAULT_PUPPET"]

# inside --data / $FACETEX_DATA; --drivers and --puppet override them (paths, or relative to --data)
DEFAULT_DRIVERS = "grid"
DEFAULT_PUPPET = "lfw/George_W_Bush"
ID_THRESHOLD = 0.6
FIDELITY_TARGET = 0.8
ID_FRACTION_TARGET = 0.9

COLUMNS = (
    Column("clip", "driver clip"),
    Column("frames", "frames", "d"),
    Column("lost", "lost", "d"),
    Column("mouth_r", "mouth r", ".3f"),
    Column("mouth_detected", "puppet detected", ".0%"),
    Column("id_puppet", "id dist puppet", ".3f"),
    Column("id_frac", "frames < 0.6", ".0%"),
    Column("id_driver", "id dist driver", ".3f"),
    Column("flicker_ours", "flicker ours", ".2f"),
    Column("flicker_static", "flicker static", ".2f"),
    Column("fps", "render fps", ".1f"),
)


def _pearson(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 3 or a[ok].std() == 0 or b[ok].std() == 0:
        return float("nan")
    return float(np.corrcoef(a[ok], b[ok])[0, 1])


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


def _evaluate_clip(clip: Path, persona, ref_desc, out: Path, *, size, max_frames, params, write_media: bool,
                   progress: Callable | None) -> dict:
    from ..io import write_image, write_video
    from ..nets.dlib_resnet import face_descriptor
    from ..persona.driver import mouth_opening
    from ..persona.puppet import prepare_puppetry, render_frames

    t0 = time.perf_counter()
    session = prepare_puppetry(clip, persona, max_frames=max_frames, params=params)
    t_prep = time.perf_counter() - t0
    t0 = time.perf_counter()
    ours = list(render_frames(session, size=size, background="driver"))
    t_render = time.perf_counter() - t0
    static = list(render_frames(session, size=size, background="driver", texture="static"))
    n = len(ours)
    track = session.track
    scale = ours[0]["puppet"].shape[1] / track.frame_size[0]
    # driver signals: measured like the puppet's (lost frames excluded)
    drv_open = np.full(n, np.nan)
    for r in ours:
        if track.found[r["index"]]:
            pts, _ = _frame_measures(r["driver"], descriptor=False)
            drv_open[r["index"]] = mouth_opening(pts) if pts is not None else np.nan
    p68 = session.motion.points68 * scale
    iod = np.linalg.norm(p68[:, 36] - p68[:, 45], axis=1)
    speed = np.r_[np.nan, np.linalg.norm(np.diff(p68, axis=0), axis=2).mean(axis=1) / iod[1:]]
    speed[~track.found] = np.nan
    speed[1:][~track.found[:-1]] = np.nan
    still = np.isfinite(speed) & (speed <= np.nanpercentile(speed, 33))
    # driver identity reference: every 5th tracked frame
    drv_desc = [face_descriptor(r["driver"], p68[r["index"]]) for r in ours[::5] if track.found[r["index"]]]
    drv_ref = np.mean(drv_desc, axis=0)
    pup_open, d_pup, d_drv = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    for r in ours:
        pts, desc = _frame_measures(r["puppet"])
        if pts is not None:
            i = r["index"]
            pup_open[i] = mouth_opening(pts)
            d_pup[i] = np.linalg.norm(desc - ref_desc)
            d_drv[i] = np.linalg.norm(desc - drv_ref)
        if progress:
            progress(n=1, clip=clip.stem)
    row = {
        "clip": clip.stem,
        "frames": n,
        "lost": track.n_lost,
        "mouth_r": _pearson(drv_open, pup_open),
        "mouth_detected": float(np.isfinite(pup_open).mean()),
        "id_puppet": float(np.nanmean(d_pup)) if np.isfinite(d_pup).any() else float("nan"),
        "id_frac": float(np.mean(np.nan_to_num(d_pup, nan=9.0) < ID_THRESHOLD)),
        "id_driver": float(np.nanmean(d_drv)) if np.isfinite(d_drv).any() else float("nan"),
        "flicker_ours": _flicker([r["puppet"] for r in ours], [r["alpha"] for r in ours], still),
        "flicker_static": _flicker([r["puppet"] for r in static], [r["alpha"] for r in static], still),
        "fps": n / t_render,
        "prepare_s": t_prep,
        "still_frames": int(still.sum()),
        "timings": dict(session.timings),
        "driver_opening": drv_open.tolist(),
        "puppet_opening": pup_open.tolist(),
        "shape": session.puppeteer.shape_source,
    }
    if write_media:
        mp4 = out / f"{clip.stem}_side_by_side.mp4"
        write_video(mp4, (np.concatenate([r["driver"], r["puppet"]], axis=1) for r in ours), track.fps,
                    audio_from=clip if track.has_audio else None, overwrite=True)
        idx = np.linspace(0, n - 1, 8).round().astype(int)
        y0, y1, x0, x1 = _crop_box(np.nanmean(p68[track.found], axis=0), ours[0]["puppet"].shape)
        rows = [[ours[i][k][y0:y1, x0:x1] for i in idx] for k in ("driver", "puppet")]
        rows.append([static[i]["puppet"][y0:y1, x0:x1] for i in idx])
        labels = [[f"#{i} open {drv_open[i]:.2f}" for i in idx],
                  [f"open {pup_open[i]:.2f}" if np.isfinite(pup_open[i]) else "no face" for i in idx],
                  ["static texture" if j == 0 else None for j in range(8)]]
        sheet = out / f"{clip.stem}_contact_sheet.png"
        write_image(sheet, image_grid(rows, cell=200, cell_labels=labels,
                                      col_titles=[f"frame {i}" for i in idx]), overwrite=True)
        row["media"] = {"mp4": str(mp4), "contact_sheet": str(sheet)}
    return row


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


def run_bench_puppet(drivers, puppet, out="bench_out/puppet", *,
                     clips: int | None = None, size: int | None = None, max_frames: int | None = None,
                     texture_shape: str = "collection", progress: Callable | None = None) -> dict:
    """Run the puppetry benchmark: every ``*.mpg`` / ``*.mp4`` in ``drivers`` (the first ``clips``)
    drives the persona ``puppet`` (a .persona file, or a photo folder built once and cached in
    ``out``). Writes table.md, table.csv, results.json and, for the first clip, a side-by-side
    MP4 and a contact sheet of 8 frames. Returns {"out", "rows", "files"}."""
    from ..io import write_json
    from ..persona.puppet import PuppetParams

    drivers = Path(drivers)
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
    params = PuppetParams(shape=texture_shape)
    rows = []
    for k, clip in enumerate(files):
        rows.append(_evaluate_clip(clip, persona, ref, out, size=size, max_frames=max_frames, params=params,
                                   write_media=(k == 0), progress=progress))
    summary = {"clip": "mean"}
    for c in COLUMNS[1:]:
        vals = [r[c.key] for r in rows if isinstance(r.get(c.key), (int, float)) and np.isfinite(r[c.key])]
        summary[c.key] = float(np.mean(vals)) if vals else float("nan")
    summary["frames"], summary["lost"] = int(sum(r["frames"] for r in rows)), int(sum(r["lost"] for r in rows))
    table_rows = rows + [summary]
    head = (f"# Puppetry benchmark\n\nPuppet: `{puppet}` ({len(persona)} photos); drivers: {len(files)} clip(s) "
            f"from `{drivers}`; panel size {size or 'native'}; puppet shape: {rows[0]['shape']}.\n\n"
            f"Targets: mouth r >= {FIDELITY_TARGET}; id dist to the puppet < {ID_THRESHOLD} on >= "
            f"{ID_FRACTION_TARGET:.0%} of frames and smaller than to the driver; flicker (still frames, "
            "0-255) of ours vs the static texture.\n\n")
    ok = {
        "fidelity": bool(np.isfinite(summary["mouth_r"]) and summary["mouth_r"] >= FIDELITY_TARGET),
        "identity": bool(summary["id_frac"] >= ID_FRACTION_TARGET and summary["id_puppet"] < summary["id_driver"]),
    }
    tail = f"\nfidelity target met: {ok['fidelity']}; identity target met: {ok['identity']}\n"
    paths = {"table_md": out / "table.md", "table_csv": out / "table.csv", "results": out / "results.json"}
    write_text(paths["table_md"], head + markdown_table(COLUMNS, table_rows) + tail)
    write_text(paths["table_csv"], csv_table(COLUMNS, table_rows))
    write_json(paths["results"], json_safe({"settings": {"drivers": str(drivers), "puppet": str(puppet),
                                                         "persona_file": persona_file, "size": size,
                                                         "max_frames": max_frames, "versions": versions()},
                                            "rows": rows, "summary": summary, "targets_met": ok}), overwrite=True)
    if rows and "media" in rows[0]:
        paths.update({k: Path(v) for k, v in rows[0]["media"].items()})
    return {"out": out, "rows": rows, "summary": summary, "files": paths, "targets_met": ok}


# --------------------------------------------------------------------------- CLI
def register_bench(bench_subparsers) -> argparse.ArgumentParser:
    """Add the ``puppet`` sub-parser to ``facetex bench``."""
    from ..cli._common import bounded_int, positive_int
    from ._common import add_bench_options

    p = bench_subparsers.add_parser(
        "puppet", help="puppetry: GRID clips drive a persona (mouth fidelity, identity, flicker)",
        description="Driver clips drive a persona (Tom Hanks §4, §6). Measured per clip: expression fidelity "
                    "(correlation of the driver's and the puppet's mouth opening, target >= 0.8), identity "
                    "(distance of the rendered frames to the puppet's photos < 0.6 on >= 90 %% of frames, and "
                    "larger to the driver) and flicker on still frames (expression-dependent vs static texture). "
                    "Writes table.md/.csv, results.json and, for the first clip, an MP4 and a contact sheet.")
    add_bench_options(p, "puppet", f"data root holding {DEFAULT_DRIVERS}/ and {DEFAULT_PUPPET}/")
    p.add_argument("--drivers", default=DEFAULT_DRIVERS, metavar="DIR",
                   help=f"folder of driver videos, a path or relative to --data (default {DEFAULT_DRIVERS})")
    p.add_argument("--puppet", default=DEFAULT_PUPPET, metavar="PATH",
                   help=f"puppet .persona file or photo folder, a path or relative to --data (default {DEFAULT_PUPPET})")
    p.add_argument("--clips", type=positive_int, help="use only the first N clips")
    p.add_argument("--size", type=bounded_int(32, 4096), help="longer side of the rendered frames (default: the driver's)")
    p.add_argument("--max-frames", type=positive_int, help="use only the first N frames of each clip")
    p.add_argument("--shape", choices=("collection", "generic"), default="collection",
                   help="puppet average shape: photometric stereo (falls back to generic) or the generic face")
    p.set_defaults(func=_run)
    return p


def _resolve(root: Path, value: str) -> Path:
    p = Path(value)
    if p.is_absolute() or p.exists():
        return p
    return root / p


def _run(args) -> int:
    from ..cli._common import progress_bar
    from ..io import video_info
    from ._common import data_root, finish_bench

    root = data_root(args.data) if (args.data or not (Path(args.drivers).exists() and Path(args.puppet).exists())) \
        else Path(".")
    drivers, puppet = _resolve(root, args.drivers), _resolve(root, args.puppet)
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
    with progress_bar(total=total or None, desc="bench puppet", unit="frame", disable=args.quiet) as bar:
        res = run_bench_puppet(drivers, puppet, args.out, clips=args.clips, size=args.size,
                               max_frames=args.max_frames, texture_shape=args.shape, progress=bar)
    table = Path(res["files"]["table_md"]).read_text(encoding="utf-8")
    finish_bench(args, "puppet", res["out"], res["files"], inputs={"drivers": drivers, "puppet": puppet},
                 settings={"drivers": str(drivers), "puppet": str(puppet)},
                 summary={"summary": res["summary"], "targets_met": res["targets_met"]}, table=table)
    return 0


def run_bench_puppet_cli(argv: Sequence[str] | None = None) -> int:
    """Stand-alone entry (``python -m facetex.bench.puppet``) until ``facetex bench`` is wired."""
    ap = argparse.ArgumentParser(prog="facetex bench")
    register_bench(ap.add_subparsers(dest="bench", required=True))
    args = ap.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    raise SystemExit(run_bench_puppet_cli())
