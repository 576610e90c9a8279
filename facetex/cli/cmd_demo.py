"""``facetex demo`` — the main job on the bundled sample faces, in under a minute on a CPU."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ._common import add_json, add_output, add_quiet, add_seed_device, bounded_int, check_device, print_json, progress_bar, say

CONTENT = "frl_004_neutral.jpg"
STYLE = "frl_005_neutral.jpg"
SMILING = "frl_004_smiling.jpg"
MAX_DEMO_SIZE = 256  # working size cap: the demo must finish in about a minute on 2 cores


def register(sub) -> None:
    from .cmd_transfer import _iters, _memory

    p = sub.add_parser("demo", help="run landmarks, identity, a FaceTex transfer and its metrics on bundled faces",
                       description="Landmarks, identity distances, a FaceTex transfer (and optionally the "
                                   "baselines) with its metrics on the bundled sample portraits (CC BY 4.0). "
                                   "Writes its files into --out (replacing an earlier demo's), each image "
                                   "with a JSON sidecar, and run.json for the folder.")
    add_output(p, dest="out", default="demo_out", metavar="DIR", help="output folder (default demo_out)")
    p.add_argument("--size", type=bounded_int(32, 4096), default=None, metavar="PX",
                   help=f"working size of the transfer (default: the sample faces' own size, at most "
                        f"{MAX_DEMO_SIZE}: they are never upscaled)")
    p.add_argument("--iters", type=_iters, default="60,60,60", metavar="N,N,N",
                   help="L-BFGS iterations per level (default 60,60,60)")
    p.add_argument("--methods", default="facetex", help="comma-separated: facetex,mrf,gatys (default facetex)")
    p.add_argument("--max-memory", type=_memory, metavar="SIZE",
                   help="refuse a transfer above this estimated peak (e.g. 8G; default 75%% of free RAM)")
    add_seed_device(p)
    add_quiet(p)
    add_json(p, "the demo's summary (identity distances, metrics, timings)")
    p.set_defaults(func=run)


def _label(image: np.ndarray, text: str) -> np.ndarray:
    import cv2

    img = (np.clip(image, 0, 1) * 255).astype(np.uint8).copy()
    cv2.rectangle(img, (0, 0), (img.shape[1], 22), (255, 255, 255), -1)
    cv2.putText(img, text, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return img.astype(np.float32) / 255.0


def demo_size(points_c, shape_c, points_s, shape_s, cap: int = MAX_DEMO_SIZE) -> int:
    """The largest working size at which neither face crop is upscaled (at most ``cap``)."""
    from ..transfer import face_crop_box

    sides = []
    for pts, shape in ((points_c, shape_c), (points_s, shape_s)):
        x0, y0, x1, y1 = face_crop_box(pts, shape)
        sides.append(max(x1 - x0, y1 - y0))
    return int(max(32, min(cap, *sides)))


def run(args) -> int:
    from .._provenance import provenance
    from .._resources import sample_path
    from ..errors import BadInputError, OutputError
    from ..io import check_output_path, encode_image, encode_json, read_image, write_files
    from ..landmarks import detect_face
    from ..metrics import transfer_metrics
    from ..nets.dlib_resnet import identity_distance
    from ..transfer import transfer_with_info
    from ..transfer.methods import METHODS
    from .cmd_landmarks import _overlay

    t_start = time.perf_counter()
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise BadInputError(f"--methods {args.methods!r}: use a comma-separated subset of {','.join(METHODS)}")
    check_device(args.device)
    out = Path(args.out)
    try:  # the demo writes its fixed file names into this folder (replacing an earlier demo's)
        out.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputError("not a folder: give a folder name for --out", path=out) from None
    except OSError as e:
        raise OutputError(f"cannot create the output folder ({e.strerror}): run the demo from a writable "
                          "folder or pass --out", path=out) from None
    check_output_path(out / "summary.json", overwrite=True)  # writable, not deleted: before the work
    paths = {"content": sample_path(CONTENT), "style": sample_path(STYLE), "smiling": sample_path(SMILING)}
    content, style, smiling = (read_image(paths[k]) for k in ("content", "style", "smiling"))
    face_c, face_s = detect_face(content, source=CONTENT), detect_face(style, source=STYLE)
    size = args.size or demo_size(face_c.points68, content.shape, face_s.points68, style.shape)
    written: list[Path] = []

    def put(name: str, image, record: dict | None = None) -> None:
        p = out / name
        files = {p: encode_image(p, image)}
        if record is not None:
            files[Path(f"{p}.json")] = encode_json(record)
        write_files(files, overwrite=True)
        written.extend(files)

    params = {"size": size, "iters": list(args.iters), "methods": methods, "device": args.device}
    put("landmarks.png", _overlay(content, [face_c], 0),
        provenance(command="demo: landmarks", inputs={"image": paths["content"]}, params={}, outputs=["landmarks.png"]))
    ident = {"same_person_neutral_vs_smiling": identity_distance(content, smiling),
             "different_people": identity_distance(content, style)}
    summary = {"inputs": {"content": CONTENT, "style": STYLE, "smiling": SMILING}, "identity": ident,
               "size": size, "iters": list(args.iters), "transfers": {}}
    tiles = [_label(style, "style"), _label(content, "content")]
    zoom_cols: list = []
    for method in methods:
        iters = args.iters
        from ..transfer import preset as _preset

        budget = _preset(method).eval_budget
        with progress_bar(int(sum(iters) * budget) + len(iters), desc=method, unit="eval", disable=args.quiet) as bar:
            t0 = time.perf_counter()
            image, info = transfer_with_info(
                content, style, method=method, size=size, iters=iters, seed=args.seed, device=args.device,
                max_memory=args.max_memory, content_points=face_c.points68, style_points=face_s.points68,
                progress=lambda n=1, level=0, loss=0.0, **_: bar(n, level=level, loss=f"{loss:.4g}"))
        seconds = time.perf_counter() - t0
        images = info.pop("images")
        m = transfer_metrics(image, content, style, points=(None, face_c.points68, face_s.points68))
        record = provenance(command=f"demo: transfer --method {method}", seed=args.seed,
                            inputs={"content": paths["content"], "style": paths["style"]},
                            params={"method": method, "size": size, "iters": list(iters), "device": args.device},
                            outputs=[f"transfer_{method}.png"], result=info, metrics=m)
        put(f"transfer_{method}.png", image, record)
        if method == "facetex":
            for name, key, what in (("aligned_style.png", "style_native", "the style pre-warped onto the content's "
                                     "face crop (FaceTex §2.3), at the crop's own resolution"),
                                    ("skin_content.png", "skin_content", "where the content may change: its skin"),
                                    ("skin_style.png", "skin_style", "the style's skin, warped onto the content: "
                                     "where texture may come from"),
                                    ("prior_mask.png", "prior", "the facial prior mask (FaceTex §2.2)")):
                if images.get(key) is not None:
                    put(name, images[key], provenance(command=f"demo: transfer --method {method}", seed=args.seed,
                                                      inputs={"content": paths["content"], "style": paths["style"]},
                                                      params=record["params"], outputs=[name], what=what))
            x0, y0, x1, y1 = info["region_box"]
            aligned_full = content.copy()
            aligned_full[y0:y1, x0:x1] = images["style_native"]
            zoom_cols.extend([("content", content), ("pre-warped style", aligned_full)])
        zoom_cols.append((method, image))
        summary["transfers"][method] = {"seconds": seconds, "metrics": m}
        tiles.append(_label(image, f"{method}  id->content {m['identity_content']:.2f}"))
    from ..bench._zoom import zoom_sheet

    row = np.hstack(tiles)
    zoom = zoom_sheet(zoom_cols or [("content", content)], face_c.points68, zoom=3,
                      title="skin at 100 % (3x, nearest neighbour): forehead, cheeks, chin").astype(np.float32) / 255.0
    width = max(row.shape[1], zoom.shape[1])
    pad = lambda a: np.pad(a, ((0, 8), (0, width - a.shape[1]), (0, 0)), constant_values=1.0)  # noqa: E731
    put("figure.png", np.vstack([pad(row), pad(zoom)]), provenance(
        command="demo", seed=args.seed, inputs={"content": paths["content"], "style": paths["style"]}, params=params,
        outputs=["figure.png"], what="style, content and each method's output side by side; below, zoomed skin "
                                     "crops at native resolution of the content, the pre-warped style and the outputs"))
    summary["seconds"] = time.perf_counter() - t_start
    files = {out / "summary.json": encode_json(summary),
             out / "run.json": encode_json(provenance(
                 command="demo", seed=args.seed, inputs={k: v for k, v in paths.items()}, params=params,
                 outputs=[p.name for p in written] + ["summary.json"], result=summary))}
    write_files(files, overwrite=True)
    written.extend(files)
    if args.json:
        print_json(summary)
        return 0
    lines = [f"identity distance (< 0.6: same person): same person {ident['same_person_neutral_vs_smiling']:.3f}, "
             f"different people {ident['different_people']:.3f}"]
    for method, t in summary["transfers"].items():
        mm = t["metrics"]
        lines.append(f"{method}: {t['seconds']:.1f} s at {size} px, landmark error E(xt,xc) {mm['E_content']:.2f} px², "
                     f"texture S(xt,xs) {mm['S_style']:.3f} ({mm['S_style_gain']:+.3f} over no transfer), "
                     f"skin detail {mm['detail_output']:.2f} vs the style's {mm['detail_style']:.2f}, "
                     f"eyes/brows/lips changed {mm['protected_change']:.2f}/255, background "
                     f"{mm['background_change']:.2f}/255, identity distance to the content {mm['identity_content']:.3f}")
    lines.append(f"demo finished in {summary['seconds']:.1f} s; outputs in {out}:")
    say(args, *lines, *(f"wrote {p}" for p in written))
    return 0
