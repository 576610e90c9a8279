"""``facetex bench persona``: leave-out evaluation of persona texture synthesis (Tom Hanks Fig. 5).

The persona is built without ``holdout`` photos drawn at random (``seed``) among the
usable ones; for each held-out photo the texture is synthesized for its pose-corrected
fiducials with every method and compared with its frontalized image inside the face
mask where the photo was visible: SSIM (skimage, on luminance), correlation of the
gradient magnitudes (Sobel, luminance) and the mean-colour difference (RGB, 0-255).
"Colour std" is the spread (RMS over RGB of the per-channel std) of the texture's mean
colour across the targets: the lower, the more consistent. Writes table.md, table.csv,
per_target.csv, grid.png (reference, static, weighted, prewarp, ours) and summary.json.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from ..errors import BadInputError
from ._common import Column, check_out_dir, csv_table, markdown_table, versions, write_grid, write_text

__all__ = ["run_bench_persona", "register_bench", "masked_metrics"]

DATA_SUBFOLDER = "lfw/George_W_Bush"  # inside --data / $FACETEX_DATA (or --data is this folder itself)
GRID_METHODS = ("static", "weighted", "prewarp", "ours")


def _gray(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.ascontiguousarray(img, np.float32), cv2.COLOR_RGB2GRAY)


def masked_metrics(out: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> dict:
    """SSIM, gradient-magnitude correlation and mean-colour difference of ``out`` vs ``ref``
    (float RGB in [0, 1]) inside the boolean ``mask``."""
    from skimage.metrics import structural_similarity

    ga, gb = _gray(out), _gray(ref)
    _, smap = structural_similarity(ga, gb, data_range=1.0, full=True, gaussian_weights=True, sigma=1.5,
                                    use_sample_covariance=False)
    mag = []
    for g in (ga, gb):
        gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3)
        mag.append(np.sqrt(gx * gx + gy * gy)[mask])
    corr = float(np.corrcoef(mag[0], mag[1])[0, 1])
    mean_out = out[mask].mean(axis=0)
    mean_ref = ref[mask].mean(axis=0)
    return {
        "ssim": float(smap[mask].mean()),
        "grad_corr": corr,
        "colour_diff": float(np.linalg.norm(mean_out - mean_ref) * 255),
        "mean_colour": (mean_out * 255).tolist(),
    }


def _choose_holdout(files: list[Path], holdout: int, seed: int, params, progress) -> tuple[list[dict], list[Path]]:
    """The first ``holdout`` usable photos of a seeded permutation, and the remaining files."""
    from ..persona.collection import process_photo

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
    """The persona build as an engine item (a Ray task): what ``facetex.build_persona`` does for a
    user, saved to the run folder's cache file."""
    import facetex

    facetex.build_persona(p["data"], jobs=p["jobs"], files=p["files"]).save(p["cache"], overwrite=True)
    return {"cache": p["cache"]}


def run_bench_persona(data, *, holdout: int = 20, seed: int = 0, out="bench_out/persona",
                      jobs: int = 2, sigma: float = 10.0, exact: int = 0, grid_rows: int = 8,
                      progress: Callable | None = None, engine=None) -> dict:
    """Run the leave-out evaluation; returns {"rows": per-method means, "targets": per-target
    records, "files": written paths}. ``exact`` > 0 also runs the paper's per-target pipeline
    (``precomputed=False``, slow) on that many targets to measure the precomputation's effect."""
    from ..geometry.masks import face_mask
    from ..persona import PersonaParams, build_persona, load_persona, synthesize_texture
    from ..persona.collection import _list_photos
    from ..persona.texture import prepare_persona

    if holdout < 1:
        raise BadInputError(f"--holdout must be at least 1, got {holdout}")
    out = check_out_dir(out)
    data = Path(data)
    files = _list_photos(data)
    params = PersonaParams()
    held, rest = _choose_holdout(files, holdout, seed, params, progress)
    if len(held) < holdout:
        raise BadInputError(f"only {len(held)} usable photos to hold out (asked {holdout})", path=data)
    cache = out / f"{data.name}_holdout{holdout}_seed{seed}.persona"
    t0 = time.perf_counter()
    persona = None
    if cache.exists():
        try:
            persona = load_persona(cache)
            if set(persona.photos) & {h["file"] for h in held}:
                persona = None
        except Exception:  # noqa: BLE001 - a stale cache is rebuilt
            persona = None
    built = persona is None
    if built and engine is not None:  # the build is one task of ``jobs`` CPUs on the engine (a Ray cluster)
        from ..batch import Resources, map_items

        map_items(engine, _build_item, [{"data": str(data.resolve()), "jobs": jobs, "cache": str(cache.resolve()),
                                         "files": [str(f) for f in rest]}], resources=Resources(cpus=jobs))
        persona = load_persona(cache)
    elif built:
        persona = build_persona(data, files=rest, jobs=jobs, progress=progress, params=params)
        persona.save(cache, overwrite=True)
    t_build = time.perf_counter() - t0
    t0 = time.perf_counter()
    prepare_persona(persona)
    t_prep = time.perf_counter() - t0

    H, W = persona.images.shape[1:3]
    targets, grid, labels = [], [], []
    times = {m: [] for m in GRID_METHODS}
    for k, h in enumerate(held):
        ref = h["image"].astype(np.float32) / 255
        v = h["visibility"].astype(np.float32) / 255
        v = v + (1 - v) * v[:, ::-1]
        mask = (face_mask(h["points68"], (H, W)) > 0.5) & (v > 0.5)
        rec = {"file": h["file"], "yaw": h["pose"][0]}
        row = [ref]
        for m in GRID_METHODS:
            t = time.perf_counter()
            img = synthesize_texture(persona, fiducials=h["fiducials"], method=m, sigma=sigma)
            times[m].append(time.perf_counter() - t)
            for key, val in masked_metrics(img, ref, mask).items():
                rec[f"{m}_{key}"] = val
            row.append(img)
            if m == "ours" and k < exact:
                t = time.perf_counter()
                ex = synthesize_texture(persona, fiducials=h["fiducials"], method="ours", sigma=sigma,
                                        precomputed=False)
                rec["exact_time_s"] = time.perf_counter() - t
                for key, val in masked_metrics(ex, ref, mask).items():
                    rec[f"exact_{key}"] = val
                rec["exact_vs_ours_mad"] = float(np.abs(ex - img)[mask].mean() * 255)
                rec["_exact_img"] = ex
        targets.append(rec)
        if k < grid_rows:
            grid.append(row + ([rec.pop("_exact_img")] if "_exact_img" in rec else []))
            labels.append([h["file"].rsplit(".", 1)[0][-4:]] + [None] * (len(grid[-1]) - 1))
        rec.pop("_exact_img", None)
        if progress:
            progress(n=1, stage="targets")

    rows = []
    names = list(GRID_METHODS) + (["exact"] if exact > 0 else [])
    for m in names:
        recs = [t for t in targets if f"{m}_ssim" in t]
        cols = np.array([t[f"{m}_mean_colour"] for t in recs])
        rows.append({
            "method": m if m != "exact" else "ours, per-target (paper pipeline)",
            "n": len(recs),
            "ssim": float(np.mean([t[f"{m}_ssim"] for t in recs])),
            "grad_corr": float(np.mean([t[f"{m}_grad_corr"] for t in recs])),
            "colour_diff": float(np.mean([t[f"{m}_colour_diff"] for t in recs])),
            "colour_std": float(np.sqrt((cols.std(axis=0) ** 2).mean())) if len(cols) > 1 else float("nan"),
            "time_ms": float(np.median(times[m]) * 1000) if m in times else
            float(np.median([t["exact_time_s"] for t in recs]) * 1000),
        })
    columns = [Column("method", "method"), Column("n", "targets"), Column("ssim", "SSIM ↑", ".4f"),
               Column("grad_corr", "grad. corr. ↑", ".4f"), Column("colour_diff", "colour diff ↓", ".2f"),
               Column("colour_std", "colour std across targets ↓", ".2f"),
               Column("time_ms", "median time / target (ms)", ".1f")]
    head = (f"Persona texture leave-out evaluation: {data.name}, {len(persona)} photos in the persona "
            f"({len(persona.skipped)} skipped), {len(held)} held out (seed {seed}), sigma {sigma}.\n"
            f"Build {t_build:.0f} s ({'built' if built else 'cached'}), precompute {t_prep:.1f} s.\n\n")
    extra = ""
    if exact > 0:
        mads = [t["exact_vs_ours_mad"] for t in targets if "exact_vs_ours_mad" in t]
        extra = (f"\nPrecomputed vs per-target pipeline on {len(mads)} targets: mean |difference| "
                 f"{np.mean(mads):.2f} / 255 inside the mask.\n")
    files_out = {
        "table.md": write_text(out / "table.md", head + markdown_table(columns, rows) + extra),
        "table.csv": write_text(out / "table.csv", csv_table(columns, rows)),
    }
    tcols = [Column(k, k) for k in targets[0] if not k.endswith("mean_colour")]
    files_out["per_target.csv"] = write_text(out / "per_target.csv", csv_table(tcols, targets))
    titles = ["reference", *GRID_METHODS] + (["ours (per-target)"] if exact > 0 else [])
    files_out["grid.png"] = write_grid(out / "grid.png", grid, col_titles=titles, cell_labels=labels, cell=192)
    from ..io import write_json

    summary = {"data": str(data), "holdout": holdout, "seed": seed, "sigma": sigma, "photos": len(persona),
               "skipped": persona.skipped, "held_out": [h["file"] for h in held], "rows": rows,
               "build_s": t_build, "precompute_s": t_prep, "versions": versions()}
    files_out["summary.json"] = write_json(out / "summary.json", summary, overwrite=True)
    return {"rows": rows, "targets": targets, "files": {k: str(v) for k, v in files_out.items()},
            "table": head + markdown_table(columns, rows) + extra}


def register_bench(sub) -> None:
    """Add ``persona`` to the ``facetex bench`` sub-commands (wired by the bench parser)."""
    from ..cli._common import bounded_int, finite_float, positive_int
    from ._common import add_bench_options

    p = sub.add_parser("persona", help="leave-out evaluation of persona textures (Tom Hanks Fig. 5)",
                       description="Build a persona without --holdout photos, synthesize each held-out photo's "
                                   "texture with every method and compare it with the photo: table.md/.csv, "
                                   "per_target.csv, grid.png, summary.json.")
    add_bench_options(p, "persona", f"data root holding {DATA_SUBFOLDER}/, or a folder of photos of one person")
    p.add_argument("--holdout", type=positive_int, default=20, help="photos held out as targets (default 20)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the held-out choice (default 0)")
    p.add_argument("--jobs", type=bounded_int(1, 64), default=2, help="worker processes for the build (default 2)")
    p.add_argument("--sigma", type=finite_float(0.0, open_lo=True), default=10.0, help="Eq. 3 sigma (default 10)")
    p.add_argument("--exact", type=bounded_int(0), default=0, metavar="N",
                   help="also run the paper's per-target pipeline on N targets (slow)")
    from ..cli._common import add_engine_options

    add_engine_options(p, jobs=False)  # --engine ray: the build runs as one task of --jobs CPUs on the cluster
    p.set_defaults(func=_run_cli)


def _run_cli(args) -> int:
    from ..cli._common import progress_bar
    from ..persona.collection import _list_photos
    from ._common import data_folder, data_root, finish_bench

    data = data_folder(data_root(args.data), DATA_SUBFOLDER)
    n = len(_list_photos(data))
    total = args.holdout + 2 * max(0, n - args.holdout) + args.holdout  # hold-out choice, build, targets
    import contextlib

    from ..cli._common import engine_from_args

    engine = engine_from_args(args) if args.engine == "ray" else None  # local: the build's own --jobs workers
    with engine or contextlib.nullcontext(), \
            progress_bar(total=total, desc="bench persona", unit="step", disable=args.quiet) as update:
        res = run_bench_persona(data, holdout=args.holdout, seed=args.seed, out=args.out, jobs=args.jobs,
                                sigma=args.sigma, exact=args.exact, progress=update, engine=engine)
    finish_bench(args, "persona", args.out, res["files"], inputs={"data": data}, settings={"data": str(data)},
                 summary={"rows": res["rows"]}, table=res["table"])
    return 0
