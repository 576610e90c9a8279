"""``facetex demo`` — the main job on the bundled sample faces, in a few minutes on a CPU."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ._common import add_seed_device, progress_bar

CONTENT = "frl_004_neutral.jpg"
STYLE = "frl_005_neutral.jpg"


def register(sub) -> None:
    p = sub.add_parser("demo", help="run landmarks, identity, a FaceTex transfer and its metrics on bundled faces")
    p.add_argument("--out", default="demo_out", help="output folder (default demo_out)")
    p.add_argument("--size", type=int, default=256, help="working size of the transfer (default 256)")
    p.add_argument("--iters", default="60,60,60", help="L-BFGS iterations per level (default 60,60,60)")
    p.add_argument("--methods", default="facetex", help="comma-separated: facetex,mrf,gatys (default facetex)")
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
    from .cmd_transfer import _iters

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    content = read_image(sample_path(CONTENT))
    style = read_image(sample_path(STYLE))
    smiling = read_image(sample_path("frl_004_smiling.jpg"))
    face_c, face_s = detect_face(content, source=CONTENT), detect_face(style, source=STYLE)
    write_image(out / "landmarks.png", _overlay(content, [face_c], 0))
    ident = {"same_person_neutral_vs_smiling": identity_distance(content, smiling),
             "different_people": identity_distance(content, style)}
    summary = {"inputs": {"content": CONTENT, "style": STYLE}, "identity": ident, "transfers": {}}
    tiles = [_label(style, "style"), _label(content, "content")]
    for method in [m.strip() for m in args.methods.split(",") if m.strip()]:
        iters = _iters(args.iters)
        with progress_bar(sum(iters) * 5 // 4 + len(iters), desc=method, unit="eval") as bar:
            t0 = time.perf_counter()
            image, info = transfer_with_info(
                content, style, method=method, size=args.size, iters=iters, seed=args.seed, device=args.device,
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
