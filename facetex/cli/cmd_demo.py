"""``facetex demo`` — the main job on the bundled sample faces, in a few minutes on a CPU."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ._common import add_seed_device, bounded_int, check_device, progress_bar

CONTENT = "frl_004_neutral.jpg"
STYLE = "frl_005_neutral.jpg"


def register(sub) -> None:
    from .cmd_transfer import _iters, _memory

    p = sub.add_parser("demo", help="run landmarks, identity, a FaceTex transfer and its metrics on bundled faces")
    p.add_argument("--out", default="demo_out", help="output folder (default demo_out)")
    p.add_argument("--size", type=bounded_int(32, 4096), default=256, help="working size of the transfer (default 256)")
    p.add_argument("--iters", type=_iters, default="60,60,60", help="L-BFGS iterations per level (default 60,60,60)")
    p.add_argument("--methods", default="facetex", help="comma-separated: facetex,mrf,gatys (default facetex)")
    p.add_argument("--max-memory", type=_memory,
                   help="refuse a transfer above this estimated peak (e.g. 8G; default 75%% of free RAM)")
    add_seed_device(p)
    p.set_defaults(func=run)


def _label(image: np.ndarray, text: str) -> np.ndarray:
    import cv2

    img = (np.clip(image, 0, 1) * 255).astype(np.uint8).copy()
    cv2.rectangle(img, (0, 0), (img.shape[1], 22), (255, 255, 255), -1)
    cv2.putText(img, text, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return img.astype(np.float32) / 255.0


def run(args) -> int:
    from .._resources import sample_path
    from ..io import read_image, write_image, write_json
    from ..landmarks import detect_face
    from ..metrics import transfer_metrics
    from ..nets.dlib_resnet import identity_distance
    from ..transfer import transfer_with_info
    from .cmd_landmarks import _overlay
    from ..errors import BadInputError, OutputError
    from ..io import check_output_path
    from ..transfer.methods import METHODS

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
    content = read_image(sample_path(CONTENT))
    style = read_image(sample_path(STYLE))
    smiling = read_image(sample_path("frl_004_smiling.jpg"))
    face_c, face_s = detect_face(content, source=CONTENT), detect_face(style, source=STYLE)
    write_image(out / "landmarks.png", _overlay(content, [face_c], 0))
    ident = {"same_person_neutral_vs_smiling": identity_distance(content, smiling),
             "different_people": identity_distance(content, style)}
    summary = {"inputs": {"content": CONTENT, "style": STYLE}, "identity": ident, "transfers": {}}
    tiles = [_label(style, "style"), _label(content, "content")]
    for method in methods:
        iters = args.iters
        with progress_bar(sum(iters) * 5 // 4 + len(iters), desc=method, unit="eval") as bar:
            t0 = time.perf_counter()
            image, info = transfer_with_info(
                content, style, method=method, size=args.size, iters=iters, seed=args.seed, device=args.device,
                max_memory=args.max_memory,
                content_points=face_c.points68, style_points=face_s.points68,
                progress=lambda n=1, level=0, loss=0.0: bar(n, level=level, loss=f"{loss:.4g}"))
        images = info.pop("images")
        write_image(out / f"transfer_{method}.png", image)
        if method == "facetex":
            write_image(out / "aligned_style.png", images["style_w"])
            if images["prior"] is not None:
                write_image(out / "prior_mask.png", images["prior"])
        write_json(out / f"transfer_{method}.png.json", info)
        m = transfer_metrics(image, content, style, points=(None, face_c.points68, face_s.points68))
        summary["transfers"][method] = {"seconds": time.perf_counter() - t0, "metrics": m}
        tiles.append(_label(image, f"{method}  id->content {m['identity_content']:.2f}"))
    write_image(out / "figure.png", np.hstack(tiles))
    write_json(out / "summary.json", summary)
    print(json.dumps(summary, indent=1))
    print(f"\ndemo outputs in {out.resolve()}:")
    for f in sorted(out.iterdir()):
        print(f"  {f.name}")
    return 0
