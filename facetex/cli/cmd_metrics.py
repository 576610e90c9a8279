"""``facetex metrics OUTPUT CONTENT STYLE`` — FaceTex §3.1 metrics of a transfer output."""

from __future__ import annotations

from ._common import print_json


def register(sub) -> None:
    p = sub.add_parser("metrics", help="landmark error, texture similarity, identity distance and the skin measures "
                                       "(low-frequency ΔE, hair and stubble leakage, coverage, detail moved, marks) "
                                       "of a transfer output")
    p.add_argument("output", help="the transferred image x_t")
    p.add_argument("content", help="the content image x_c")
    p.add_argument("style", help="the style image x_s")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    import warnings

    from ..io import read_image_reduced
    from ..landmarks import detect_face
    from ..metrics import METRICS_MAX_PIXELS, transfer_metrics

    paths = (args.output, args.content, args.style)
    images = []
    for p in paths:  # reduced on load: the output and the content (one size) to the same size
        image, scale = read_image_reduced(p, METRICS_MAX_PIXELS)
        if scale != (1.0, 1.0):
            h, w = image.shape[:2]
            warnings.warn(f"{p}: {round(w / scale[0])}x{round(h / scale[1])} image reduced to {w}x{h} for the "
                          f"metrics (at most {METRICS_MAX_PIXELS // 10**6} megapixels)")
        images.append(image)
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
        r = result
        print(f"low-frequency skin ΔE (blur 0.1 x eye distance): mean {r['lowfreq_dE']:.2f}, worst patch "
              f"{r['lowfreq_dE_max_region']:.2f}")
        print(f"hair leakage (forehead change coherence): {r['hair_leakage']:.3f} (pasting the style: "
              f"{r['hair_leakage_style']:.3f})")
        print(f"dark specks per 1000 px on upper lip and chin: output {r['stubble_output']:.2f}, content "
              f"{r['stubble_content']:.2f}, style {r['stubble_style']:.2f} "
              f"(moved {r['stubble_moved']:+.2f} of the way)")
        print(f"skin coverage (fraction changed): {r['coverage']:.2f}; fine detail moved {r['detail_moved']:+.2f} of "
              f"the way (cheeks where the style is rougher {r['detail_moved_cheeks']:+.2f}, over their skin only "
              f"{r['detail_moved_cheeks_skin']:+.2f})")
        print(f"marks: content {r['marks_content']:.0f} ({r['marks_kept']:.0%} kept), style {r['marks_style']:.0f} "
              f"({r['marks_arrived']:.0%} arrived)")
    return 0
