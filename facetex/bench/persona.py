"""``facetex bench persona``: leave-out evaluation of persona texture synthesis (Tom Hanks Fig. 5).

The persona is built without ``holdout`` photos drawn at random (``seed``) among the
usable ones; for each held-out photo the texture is synthesized for its pose-corrected
fiducials with every method and compared with its frontalized image where the photo
itself saw the face (its own visibility > 0.5, mirrored fill excluded), in three regions:
the whole face (jaw + forehead), the mouth and the eyes with the brows (the hard 0.5 level
of the region masks of :func:`facetex.persona.weights.region_masks`, at the held-out
photo's own landmarks). Scores: SSIM (skimage, luminance, Gaussian window sigma 1.5, the
map averaged over the region), correlation of the gradient magnitudes (Sobel, luminance)
and the mean-colour difference (RGB, 0-255). "Colour std" is the spread (RMS over RGB of
the per-channel std) of the texture's mean colour across the targets: the lower, the
more consistent. Methods: the paper's Fig. 5 baselines (static average; weighted and
prewarp with the paper's global weights, sigma 10), the paper's method ("paper": our
pipeline with the global Eq. 3 weights) and ours (the default weights). Gains of ours
over static are reported with their standard error over the targets.

Writes table.md, table.csv, per_target.csv, results.json (settings, per-method means, teeth
scores; the JSON file name every bench uses), grid.png (full textures at
native resolution: reference, the methods), zoom_<region>.png sheets (mouth, eyes,
brow, chin, boundary crops at native resolution enlarged 3x, nearest neighbour: rows =
targets, columns = reference, static, paper, ours) and teeth.png (the collection's broad
smiles with teeth, each left out and re-synthesized: reference, static, paper, ours).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from .._methods import PERSONA_ORDER
from ..errors import BadInputError
from ..landmarks import eye_distance
from ._common import Column, check_out_dir, csv_table, markdown_table, versions, write_grid, write_text
from ._zoom import crop_padded

__all__ = ["run_bench_persona", "register_bench", "masked_metrics", "evaluation_masks", "region_scores",
           "zoom_boxes"]

DATA_SUBFOLDER = "lfw/George_W_Bush"  # inside --data / $FACETEX_DATA (or --data is this folder itself)
#: (row name, method, weights): the paper's baselines use the paper's (global) weights
ROWS = tuple(zip(PERSONA_ORDER, ("static", "weighted", "prewarp", "ours", "ours"),
                 (None, "global", "global", "global", None)))  # Fig. 5's order, one place: facetex._methods
REGIONS = ("face", "mouth", "eyes")
ZOOM_COLUMNS = ("static", "paper", "ours")


def _gray(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.ascontiguousarray(img, np.float32), cv2.COLOR_RGB2GRAY)


def _ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    from skimage.metrics import structural_similarity

    _, smap = structural_similarity(_gray(a), _gray(b), data_range=1.0, full=True, gaussian_weights=True,
                                    sigma=1.5, use_sample_covariance=False)
    return smap


def _grad_mag(g: np.ndarray) -> np.ndarray:
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3)
    return np.sqrt(gx * gx + gy * gy)


def region_scores(out: np.ndarray, ref: np.ndarray, masks: dict) -> dict:
    """{region: {ssim, grad_corr, colour_diff, mean_colour}} of ``out`` vs ``ref`` (float RGB in
    [0, 1]) inside each boolean mask of ``masks``."""
    smap = _ssim_map(out, ref)
    ga, gb = _grad_mag(_gray(out)), _grad_mag(_gray(ref))
    res = {}
    for name, mask in masks.items():
        if mask.sum() < 16:
            res[name] = {"ssim": float("nan"), "grad_corr": float("nan"), "colour_diff": float("nan"),
                         "mean_colour": [float("nan")] * 3}
            continue
        mean_out, mean_ref = out[mask].mean(axis=0), ref[mask].mean(axis=0)
        res[name] = {
            "ssim": float(smap[mask].mean()),
            "grad_corr": float(np.corrcoef(ga[mask], gb[mask])[0, 1]),
            "colour_diff": float(np.linalg.norm(mean_out - mean_ref) * 255),
            "mean_colour": (mean_out * 255).tolist(),
        }
    return res


def masked_metrics(out: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> dict:
    """SSIM, gradient-magnitude correlation and mean-colour difference of ``out`` vs ``ref``
    (float RGB in [0, 1]) inside the boolean ``mask``."""
    return region_scores(out, ref, {"m": mask})["m"]


def evaluation_masks(points68: np.ndarray, visibility: np.ndarray) -> dict:
    """{"face", "mouth", "eyes"} boolean masks (H, W) of a frontalized photo: the region at its
    landmarks where the photo itself saw the face (visibility > 0.5)."""
    from ..geometry.masks import face_mask
    from ..persona.weights import region_masks

    H, W = visibility.shape
    seen = visibility > 0.5
    face = (face_mask(points68, (H, W)) > 0.5) & seen
    rm = region_masks(points68, (H, W), ("mouth", "eyes", "face"))
    return {"face": face, "mouth": (rm[0] > 0.5) & face, "eyes": (rm[1] > 0.5) & face}


def zoom_boxes(points68: np.ndarray) -> dict:
    """{region: (x, y, w, h)} crop boxes at a face's 68 landmarks (canonical frame): mouth, eyes,
    brow (glabella and forehead), chin, boundary (the left cheek's edge)."""
    p = np.asarray(points68, np.float64)
    iod = eye_distance(p)
    centres = {
        "mouth": (p[48] + p[54]) / 2,
        "eyes": (p[36:48].mean(0)),
        "brow": (p[21] + p[22]) / 2 - [0, 0.25 * iod],
        "chin": p[8] - [0, 0.15 * iod],
        "boundary": p[3] + [0.1 * iod, -0.2 * iod],
    }
    sizes = {"mouth": (1.3, 0.8), "eyes": (2.0, 0.6), "brow": (1.2, 0.7), "chin": (1.2, 0.7),
             "boundary": (0.7, 1.0)}
    out = {}
    for k, c in centres.items():
        w, h = int(round(sizes[k][0] * iod)), int(round(sizes[k][1] * iod))
        out[k] = (int(round(c[0] - w / 2)), int(round(c[1] - h / 2)), w, h)
    return out


def _crop(img: np.ndarray, box, zoom: int = 3) -> np.ndarray:
    return crop_padded(np.asarray(img, np.float32), box, zoom, fill=0.5)


def write_zoom_sheets(out: Path, items: list[dict], columns=("reference",) + ZOOM_COLUMNS) -> dict:
    """zoom_<region>.png: per target a row of native-resolution crops (3x, nearest) of the
    reference and the methods ``columns`` at the target's landmarks."""
    from ..io import write_image

    files = {}
    if not items:
        return files
    for region in zoom_boxes(items[0]["points68"]):
        rows = []
        for it in items:
            box = zoom_boxes(it["points68"])[region]
            crops = [_crop(it["images"][c], box) for c in columns]
            gap = np.ones((crops[0].shape[0], 4, 3), np.float32)
            row = crops[0]
            for c in crops[1:]:
                row = np.concatenate([row, gap, c], axis=1)
            rows.append(row)
        wmax = max(r.shape[1] for r in rows)
        rows = [np.pad(r, ((0, 4), (0, wmax - r.shape[1]), (0, 0)), constant_values=1.0) for r in rows]
        head = np.full((28, wmax, 3), 255, np.uint8)
        cw = rows[0].shape[1] // len(columns)
        for i, c in enumerate(columns):
            cv2.putText(head, c, (i * cw + 6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
        sheet = np.concatenate([head.astype(np.float32) / 255] + rows, axis=0)
        files[f"zoom_{region}.png"] = write_image(out / f"zoom_{region}.png", np.clip(sheet, 0, 1), overwrite=True)
    return files


def teeth_score(image_u8: np.ndarray, points68: np.ndarray) -> float:
    """Fraction of the inner-lip polygon (iBUG 60-67) that is bright and unsaturated (teeth),
    times whether the lips are apart (inner-lip gap > 0.12 IOD): a broad smile with teeth scores
    high. Used to pick the smiles of the teeth sheet."""
    p = np.asarray(points68, np.float64)
    iod = eye_distance(p)
    if np.linalg.norm(p[66] - p[62]) < 0.12 * iod:
        return 0.0
    m = np.zeros(image_u8.shape[:2], np.uint8)
    cv2.fillPoly(m, [np.round(p[60:68]).astype(np.int32)], 1)
    if m.sum() < 20:
        return 0.0
    hsv = cv2.cvtColor(np.ascontiguousarray(image_u8), cv2.COLOR_RGB2HSV)[m > 0]
    return float(((hsv[:, 2] > 150) & (hsv[:, 1] < 90)).mean())


def leave_one_out(persona, i: int):
    """The persona without photo i (the collection flow and appearance subspace were computed with
    it; one photo of hundreds hardly moves them)."""
    import dataclasses

    keep = np.array([j for j in range(len(persona)) if j != i])
    arrays = {k: getattr(persona, k)[keep] for k in ("images", "visibility", "fiducials", "points68", "poses", "flows")}
    return dataclasses.replace(persona, _cache={}, photos=[persona.photos[j] for j in keep], **arrays)


def write_teeth_sheet(out: Path, persona, params, n: int = 4) -> tuple[Path | None, list[dict]]:
    """teeth.png: the ``n`` photos of the collection with the most visible teeth (:func:`teeth_score`),
    each left out of the collection and synthesized from its fiducials: mouth crops of the
    reference, static, paper and ours (rows). Returns the path and per-photo records."""
    import dataclasses

    from ..io import write_image
    from ..persona import synthesize_texture

    scores = np.array([teeth_score(persona.images[i], persona.points68[i]) for i in range(len(persona))])
    picks = [int(i) for i in np.argsort(-scores)[:n] if scores[i] > 0.3]
    rows, recs = [], []
    for i in picks:
        q = leave_one_out(persona, i)
        ref = persona.images[i].astype(np.float32) / 255
        imgs = [ref]
        for name, method, weights in (("static", "static", None), ("paper", "ours", "global"), ("ours", "ours", None)):
            tp = params if weights is None else dataclasses.replace(params, weights=weights)
            imgs.append(synthesize_texture(q, fiducials=persona.fiducials[i], method=method, params=tp))
        box = zoom_boxes(persona.points68[i])["mouth"]
        crops = [_crop(x, box) for x in imgs]
        # teeth visible = the synthesized inner mouth is bright: its teeth score as the reference's
        recs.append({"file": persona.photos[i], "reference": float(scores[i]),
                     **{c: teeth_score(np.clip(np.rint(x * 255), 0, 255).astype(np.uint8), persona.points68[i])
                        for c, x in zip(("static", "paper", "ours"), imgs[1:])}})
        gap = np.ones((crops[0].shape[0], 4, 3), np.float32)
        rows.append(np.concatenate(sum(([c, gap] for c in crops), [])[:-1], axis=1))
    if not rows:
        return None, recs
    wmax = max(r.shape[1] for r in rows)
    sheet = np.concatenate([np.pad(r, ((0, 4), (0, wmax - r.shape[1]), (0, 0)), constant_values=1.0) for r in rows])
    return write_image(out / "teeth.png", np.clip(sheet, 0, 1), overwrite=True), recs


def _choose_holdout(files: list[Path], holdout: int, seed: int, params, progress) -> tuple[list[dict], list[Path]]:
    """The first ``holdout`` usable photos of a seeded permutation, and the remaining files."""
    from ..persona.build import process_photo

    order = np.random.default_rng(seed).permutation(len(files))
    held = []
    for k in order:
        if len(held) == holdout:
            break
        r = process_photo(files[k], params)
        if "reason" not in r:
            held.append(r)
            if progress:
                progress(n=1, stage="holdout")
    names = {h["file"] for h in held}
    rest = [f for f in files if f.name not in names]
    return held, rest


def _build_item(p: dict) -> dict:
    """The persona build as an engine item (a Ray task): the same build as the local run's,
    saved to the run folder's cache file."""
    from ..persona import build_persona

    build_persona(p["data"], jobs=p["jobs"], files=p["files"], params=p["params"]).save(p["cache"], overwrite=True)
    return {"cache": p["cache"]}


def load_or_build(data: Path, out: Path, holdout: int, seed: int, jobs: int, progress=None, params=None,
                  engine=None):
    """(persona without the held-out photos (cached in ``out``), held-out records, built?, build s).
    ``engine`` (started): the build runs there as one item of ``jobs`` CPUs (e.g. on a Ray cluster)."""
    from ..persona import PersonaParams
    from ..persona.build import _list_photos

    files = _list_photos(data)
    params = params or PersonaParams()
    held, rest = _choose_holdout(files, holdout, seed, params, progress)
    if len(held) < holdout:
        raise BadInputError(f"only {len(held)} usable photos to hold out (asked {holdout})", path=data)
    cache = out / f"{data.name}_holdout{holdout}_seed{seed}.persona"
    return _persona_without(data, rest, held, cache, jobs, progress, params, engine)


def _fold_records(files: list[Path], folds: int, seed: int, params, progress) -> list[list[dict]]:
    """The usable photos' records split into ``folds`` folds by a seeded permutation."""
    from ..persona.build import process_photo

    usable = []
    for f in files:
        r = process_photo(f, params)
        if "reason" not in r:
            usable.append(r)
        if progress:
            progress(n=1, stage="photos")
    order = np.random.default_rng(seed).permutation(len(usable))
    return [[usable[j] for j in sorted(order[k::folds])] for k in range(folds)]


def load_or_build_folds(data: Path, out: Path, folds: int, seed: int, jobs: int, progress=None, params=None,
                        engine=None):
    """k-fold leave-out: [(persona without fold k (cached in ``out``), fold k's records, built?, build s)]
    for k = 0 .. ``folds`` - 1; every usable photo is a target once, each persona holds the
    other folds' photos (a persona of 1 - 1/k of the collection)."""
    from ..persona import PersonaParams
    from ..persona.build import _list_photos

    files = _list_photos(data)
    params = params or PersonaParams()
    parts = _fold_records(files, folds, seed, params, progress)
    if min(len(p) for p in parts) < 1:
        raise BadInputError(f"only {sum(len(p) for p in parts)} usable photos for {folds} folds", path=data)
    res = []
    for k, held in enumerate(parts):
        names = {h["file"] for h in held}
        rest = [f for f in files if f.name not in names]
        cache = out / f"{data.name}_fold{k}of{folds}_seed{seed}.persona"
        res.append(_persona_without(data, rest, held, cache, jobs, progress, params, engine))
    return res


def _persona_without(data: Path, rest: list[Path], held: list[dict], cache: Path, jobs: int, progress, params,
                     engine):
    from ..persona import build_persona, load_persona

    t0 = time.perf_counter()
    persona = None
    if cache.exists():
        try:
            persona = load_persona(cache)
            if set(persona.photos) & {h["file"] for h in held} or persona.params != params:
                persona = None
        except Exception:  # noqa: BLE001 - a stale cache is rebuilt
            persona = None
    built = persona is None
    if built and engine is not None:  # the build is one task of ``jobs`` CPUs on the engine (a Ray cluster)
        from ..batch import Resources, map_items

        map_items(engine, _build_item, [{"data": str(data.resolve()), "jobs": jobs, "cache": str(cache.resolve()),
                                         "files": [str(f) for f in rest], "params": params}],
                  resources=Resources(cpus=jobs))
        persona = load_persona(cache)
    elif built:
        persona = build_persona(data, files=rest, jobs=jobs, progress=progress, params=params)
        persona.save(cache, overwrite=True)
    return persona, held, built, time.perf_counter() - t0


def evaluate(persona, held: list[dict], *, params=None, rows=ROWS, keep_images: int = 0,
             progress: Callable | None = None) -> tuple[list[dict], list[dict]]:
    """Per held-out target: scores of every row of ``rows`` ((name, method, weights or None =
    ``params``' default)). Returns (records, image items of the first ``keep_images`` targets)."""
    import dataclasses

    from ..persona import TextureParams, synthesize_texture

    tp = params or TextureParams()
    records, items = [], []
    for k, h in enumerate(held):
        ref = h["image"].astype(np.float32) / 255
        masks = evaluation_masks(h["points68"], h["visibility"].astype(np.float32) / 255)
        rec = {"file": h["file"], "yaw": h["pose"][0], "mouth_expression": mouth_expression(persona, h["fiducials"]),
               **{f"px_{r}": int(m.sum()) for r, m in masks.items()}}
        imgs = {"reference": ref}
        for name, method, weights in rows:
            p = tp if weights is None else dataclasses.replace(tp, weights=weights)
            t = time.perf_counter()
            img = synthesize_texture(persona, fiducials=h["fiducials"], method=method, params=p)
            rec[f"{name}_time_s"] = time.perf_counter() - t
            for region, sc in region_scores(img, ref, masks).items():
                for key, val in sc.items():
                    rec[f"{name}_{region}_{key}"] = val
            imgs[name] = img
        records.append(rec)
        if k < keep_images:
            items.append({"file": h["file"], "points68": h["points68"], "images": imgs})
        if progress:
            progress(n=1, stage="targets")
    return records, items


def mouth_expression(persona, fiducials) -> float:
    """How far a target's mouth is from the collection's average mouth: its distance in the
    regional weights' normalised mouth coordinates (:mod:`facetex.persona.weights`) to the mean
    of the persona's photos, over the photos' own median distance (1: a typical photo)."""
    from ..persona import TextureParams
    from ..persona.texture import _fiducials49, expression_model

    model = expression_model(persona, TextureParams())
    j = model.names.index("mouth")
    coords = model.regions[j].coords
    mean = coords.mean(axis=0)
    own = model.coordinates(_fiducials49(fiducials)[None])[j][0]
    return float(np.linalg.norm(own - mean) / max(float(np.median(np.linalg.norm(coords - mean, axis=1))), 1e-12))


def gain_by_expression(records: list[dict], name: str = "ours", parts: int = 3) -> list[float]:
    """Mean mouth SSIM gain of row ``name`` over static in ``parts`` equal groups of the targets
    by :func:`mouth_expression`, nearest the average mouth first (NaN for an empty group)."""
    d = np.array([t["mouth_expression"] for t in records], np.float64)
    g = np.array([t[f"{name}_mouth_ssim"] - t["static_mouth_ssim"] for t in records], np.float64)
    order = np.argsort(d, kind="stable")
    return [float(np.nanmean(g[idx])) if len(idx) else float("nan") for idx in np.array_split(order, parts)]


def summarize(records: list[dict], rows=ROWS) -> list[dict]:
    """Per row: mean scores per region, colour spread, median time; and the gain of each row over
    static in SSIM with its standard error over the targets."""
    out = []
    for name, _, _ in rows:
        r = {"method": name, "n": len(records)}
        for region in REGIONS:
            v = np.array([t[f"{name}_{region}_ssim"] for t in records], np.float64)
            base = np.array([t[f"static_{region}_ssim"] for t in records], np.float64)
            d = v - base
            ok = np.isfinite(d)
            r[f"{region}_ssim"] = float(np.nanmean(v))
            r[f"{region}_gain"] = float(d[ok].mean()) if ok.any() else float("nan")
            r[f"{region}_gain_se"] = float(d[ok].std(ddof=1) / np.sqrt(ok.sum())) if ok.sum() > 1 else float("nan")
        r["face_grad_corr"] = float(np.nanmean([t[f"{name}_face_grad_corr"] for t in records]))
        r["face_colour_diff"] = float(np.nanmean([t[f"{name}_face_colour_diff"] for t in records]))
        cols = np.array([t[f"{name}_face_mean_colour"] for t in records])
        r["colour_std"] = float(np.sqrt((cols.std(axis=0) ** 2).mean())) if len(cols) > 1 else float("nan")
        r["time_ms"] = float(np.median([t[f"{name}_time_s"] for t in records]) * 1000)
        out.append(r)
    return out


COLUMNS = [Column("method", "method"), Column("n", "targets"),
           Column("face_ssim", "SSIM face ↑", ".4f"), Column("face_gain", "Δ face vs static", "+.4f"),
           Column("mouth_ssim", "SSIM mouth ↑", ".4f"), Column("mouth_gain", "Δ mouth vs static", "+.4f"),
           Column("mouth_gain_se", "± s.e.", ".4f"),
           Column("eyes_ssim", "SSIM eyes ↑", ".4f"), Column("eyes_gain", "Δ eyes vs static", "+.4f"),
           Column("face_grad_corr", "grad. corr. ↑", ".4f"), Column("face_colour_diff", "colour diff ↓", ".2f"),
           Column("colour_std", "colour std across targets ↓", ".2f"),
           Column("time_ms", "median time / target (ms)", ".1f")]


def run_bench_persona(data, *, holdout: int = 20, seed: int = 0, out="bench_out/persona",
                      jobs: int = 2, sigma: float = 10.0, exact: int = 0, grid_rows: int = 8,
                      weights: str = "regional", neighbours: int | None = None, folds: int = 0,
                      progress: Callable | None = None, engine=None) -> dict:
    """Run the leave-out evaluation; returns {"rows": per-method means, "targets": per-target
    records, "files": written paths, "table"}. ``weights``/``neighbours``: the "ours" row's
    weights; ``sigma``: the global (paper) weights' sigma. ``exact`` > 0 also runs the paper's
    per-target pipeline (``precomputed=False``, slow) on that many targets. ``folds`` >= 2: k-fold
    instead of ``holdout`` photos: every usable photo is a target once, synthesized by a persona
    of the other folds (on a 44-photo collection 20 held out left a persona of 24 photos; 5
    folds keep 35 and score 44 targets instead of 20). ``engine``
    (:mod:`facetex.batch.engines`, started): the build runs as one item of ``jobs`` CPUs there
    (default: here, on ``jobs`` worker processes)."""
    import dataclasses

    from ..persona import TextureParams, synthesize_texture
    from ..persona.stacks import prepare_persona
    from ..persona.texture import expression_model

    if holdout < 1:
        raise BadInputError(f"--holdout must be at least 1, got {holdout}")
    if folds == 1 or folds < 0:
        raise BadInputError(f"--folds must be 0 (hold out --holdout photos) or at least 2, got {folds}")
    out = check_out_dir(out)
    data = Path(data)
    if folds:
        runs = load_or_build_folds(data, out, folds, seed, jobs, progress, engine=engine)
    else:
        runs = [load_or_build(data, out, holdout, seed, jobs, progress, engine=engine)]
    tp = TextureParams(weights=weights, sigma=sigma)
    if neighbours is not None:
        tp = dataclasses.replace(tp, neighbours=int(neighbours))
    targets, items, t_prep = [], [], 0.0
    for k, (persona_k, held_k, _, _) in enumerate(runs):
        t0 = time.perf_counter()
        prepare_persona(persona_k, tp)
        t_prep += time.perf_counter() - t0
        recs, its = evaluate(persona_k, held_k, params=tp, keep_images=max(0, grid_rows - len(items)),
                             progress=progress)
        for r in recs:
            r["fold"] = k
        targets += recs
        items += its
    persona, held = runs[0][0], [h for r in runs for h in r[1]]
    built, t_build = any(r[2] for r in runs), sum(r[3] for r in runs)
    sizes = [len(r[0]) for r in runs]
    if exact > 0:
        for rec, h in zip(targets[:exact], held[:exact]):
            t = time.perf_counter()
            ex = synthesize_texture(persona, fiducials=h["fiducials"], params=tp, precomputed=False)
            rec["exact_time_s"] = time.perf_counter() - t
            ref = h["image"].astype(np.float32) / 255
            masks = evaluation_masks(h["points68"], h["visibility"].astype(np.float32) / 255)
            for region, sc in region_scores(ex, ref, masks).items():
                rec[f"exact_{region}_ssim"] = sc["ssim"]
    rows = summarize(targets)
    model = expression_model(persona, tp) if tp.weights == "regional" else None
    how = (f"{len(persona)} photos in the persona ({len(persona.skipped)} skipped), {len(held)} held out (seed {seed})"
           if not folds else f"{folds} folds (seed {seed}): every usable photo ({len(held)}) a target of a persona of "
           f"the other folds ({min(sizes)}-{max(sizes)} photos)")
    head = (f"Persona texture leave-out evaluation: {data.name}, {how}. ours: {tp.weights} weights"
            + (f" (neighbours {tp.neighbours}, at most {tp.max_photos} photos per region; per region {model.summary()})"
               if model else "") + f"; paper and the weighted/prewarp baselines: global weights, sigma {sigma}.\n"
            f"Build {t_build:.0f} s ({'built' if built else 'cached'}), precompute {t_prep:.1f} s.\n\n")
    extra = ""
    if exact > 0:
        ex = [t for t in targets if "exact_face_ssim" in t]
        extra = (f"\nPaper's per-target pipeline (no precomputation) on {len(ex)} targets: SSIM face "
                 f"{np.mean([t['exact_face_ssim'] for t in ex]):.4f} / mouth "
                 f"{np.nanmean([t['exact_mouth_ssim'] for t in ex]):.4f} vs precomputed ours "
                 f"{np.mean([t['ours_face_ssim'] for t in ex]):.4f} / "
                 f"{np.nanmean([t['ours_mouth_ssim'] for t in ex]):.4f}.\n")
    by_expr = gain_by_expression(targets)
    extra += ("\nMouth SSIM gain of ours over static by how far the target's mouth is from the collection's "
              "average mouth (thirds of the targets, nearest first): "
              + " / ".join(f"{v:+.4f}" for v in by_expr)
              + " (a target with the average expression has little to gain over the average texture).\n")
    table = head + markdown_table(COLUMNS, rows) + extra
    files_out = {
        "table.md": write_text(out / "table.md", table),
        "table.csv": write_text(out / "table.csv", csv_table(COLUMNS, rows)),
    }
    tcols = [Column(k, k) for k in targets[0] if not k.endswith("mean_colour")]
    files_out["per_target.csv"] = write_text(out / "per_target.csv", csv_table(tcols, targets))
    names = ["reference"] + [r[0] for r in ROWS]
    grid = [[it["images"][c] for c in names] for it in items]
    labels = [[it["file"].rsplit(".", 1)[0][-4:]] + [None] * (len(names) - 1) for it in items]
    if grid:
        files_out["grid.png"] = write_grid(out / "grid.png", grid, col_titles=names, cell_labels=labels,
                                           cell=max(persona.size))
    files_out.update(write_zoom_sheets(out, items))
    teeth_path, teeth = write_teeth_sheet(out, persona, tp)
    if teeth_path is not None:
        files_out["teeth.png"] = teeth_path
        table += ("\nBroad smiles with teeth (the collection's photos with the most visible teeth, each left out "
                  "and synthesized from its fiducials; teeth score = bright unsaturated fraction of the inner "
                  "mouth, reference / static / paper / ours; teeth.png):\n"
                  + "".join(f"- {t['file']}: {t['reference']:.2f} / {t['static']:.2f} / {t['paper']:.2f} / "
                            f"{t['ours']:.2f}\n" for t in teeth))
    from ..io import write_json

    summary = {"bench": "persona", "teeth": teeth, "data": str(data), "holdout": None if folds else holdout,
               "folds": folds or None, "persona_photos": sizes, "seed": seed, "sigma": sigma, "weights": tp.weights,
               "neighbours": tp.neighbours, "expression_model": model.summary() if model else None,
               "photos": len(persona), "skipped": persona.skipped, "held_out": [h["file"] for h in held],
               "rows": rows, "mouth_gain_by_expression": by_expr, "build_s": t_build, "precompute_s": t_prep, "versions": versions()}
    files_out["results.json"] = write_json(out / "results.json", summary, overwrite=True)
    return {"rows": rows, "targets": targets, "files": {k: str(v) for k, v in files_out.items()}, "table": table}


def register_bench(sub) -> None:
    """Add ``persona`` to the ``facetex bench`` sub-commands (wired by the bench parser)."""
    from ..cli._common import bounded_int, finite_float, positive_int
    from ._common import add_bench_options

    p = sub.add_parser("persona", help="leave-out evaluation of persona textures (Tom Hanks Fig. 5)",
                       description="Build a persona without --holdout photos, synthesize each held-out photo's "
                                   "texture with every method and compare it with the photo: table.md/.csv, "
                                   "per_target.csv, results.json, grid.png, zoom_<region>.png and teeth.png "
                                   "sheets at native resolution.")
    add_bench_options(p, "persona", f"data root holding {DATA_SUBFOLDER}/, or a folder of photos of one person")
    p.add_argument("--holdout", type=positive_int, default=20, help="photos held out as targets (default 20)")
    p.add_argument("--folds", type=bounded_int(0), default=0, metavar="K",
                   help="k-fold leave-out instead of --holdout: every usable photo is a target once, synthesized "
                        "by a persona of the other K-1 folds (K personas are built; 0 = off, the default)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the held-out choice (default 0)")
    from ..cli._common import add_jobs

    add_jobs(p, "worker processes for the build")
    p.add_argument("--weights", choices=("regional", "global"), default="regional",
                   help="weights of the 'ours' row (default regional; the 'paper' row always uses global)")
    p.add_argument("--neighbours", type=positive_int, default=None, metavar="K",
                   help="regional weights: each region's sigma from the K-th nearest photo (default 3)")
    p.add_argument("--sigma", type=finite_float(0.0, open_lo=True), default=10.0,
                   help="sigma of the paper's global weights (default 10)")
    p.add_argument("--exact", type=bounded_int(0), default=0, metavar="N",
                   help="also run the paper's per-target pipeline on N targets (slow)")
    from ..cli._common import add_engine_options

    add_engine_options(p, jobs=False)  # --engine ray: the build runs as one task of --jobs CPUs on the cluster
    p.set_defaults(func=_run_cli)


def _run_cli(args) -> int:
    from ..cli._common import progress_bar
    from ..persona.build import _list_photos
    from ._common import data_folder, data_root, finish_bench

    data = data_folder(data_root(args.data), DATA_SUBFOLDER)
    if args.neighbours is not None and args.weights != "regional":
        from ..errors import BadInputError

        raise BadInputError("--neighbours applies to --weights regional (the global weights take --sigma)")
    n = len(_list_photos(data))
    if args.folds:  # the photos once, K builds of (K-1)/K of them (two steps a photo), every photo a target
        total = n + 2 * (args.folds - 1) * n + n
    else:
        total = args.holdout + 2 * max(0, n - args.holdout) + args.holdout  # hold-out choice, build, targets
    import contextlib

    from ..cli._common import engine_from_args, jobs_of

    engine = engine_from_args(args) if args.engine == "ray" else None  # local: the build's own --jobs workers
    with engine or contextlib.nullcontext(), \
            progress_bar(total=total, desc="bench persona", unit="step", disable=args.quiet) as update:
        res = run_bench_persona(data, holdout=args.holdout, seed=args.seed, out=args.out, jobs=jobs_of(args),
                                sigma=args.sigma, exact=args.exact, weights=args.weights,
                                neighbours=args.neighbours, folds=args.folds, progress=update, engine=engine)
    finish_bench(args, "persona", args.out, res["files"], inputs={"data": data}, settings={"data": str(data)},
                 summary={"rows": res["rows"]}, table=res["table"])
    return 0
