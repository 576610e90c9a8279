"""``facetex metrics OUTPUT CONTENT STYLE`` — FaceTex §3.1 metrics of a transfer output."""

from __future__ import annotations

from ._common import print_json


def register(sub) -> None:
    p = sub.add_parser("metrics", help="landmark error, texture similarity and identity distance of a transfer output")
    p.add_argument("output", help="the transferred image x_t")
    p.add_argument("content", help="the content image x_c")
    p.add_argument("style", help="the style image x_s")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..io import read_image
    from ..landmarks import detect_face
    from ..metrics import transfer_metrics

    paths = (args.output, args.content, args.style)
    images = [read_image(p) for p in paths]
    points = [detect_face(im, source=p).points68 for im, p in zip(images, paths)]
    result = transfer_metrics(*images, points=points)
    if args.json:
        print_json(result)
    else:
        print(f"landmark error E (px², 66 points at 1000 px): content {result['E_content']:.2f}"
              f" (rms {result['E_content_rms_px']:.2f} px), style {result['E_style']:.2f}"
              f" (rms {result['E_style_rms_px']:.2f} px)")
        print(f"texture similarity S (Eq. 8): content {result['S_content']:.3f}, style {result['S_style']:.3f}")
        print(f"identity distance (< 0.6 = same person): content {result['identity_content']:.3f},"
              f" style {result['identity_style']:.3f}")
    return 0
