"""``facetex transfer CONTENT STYLE -o OUT`` — FaceTex texture transfer (or a baseline)."""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

from ._common import add_overwrite, add_seed_device, progress_bar


def _iters(text: str) -> tuple[int, ...]:
    try:
        vals = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--iters takes comma-separated integers such as 100,100,100, not {text!r}") from None
    return vals


def _memory(text: str) -> int:
    t = text.strip().upper()
    mult = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
    if t and t[-1] == "B":
        t = t[:-1]
    if t and t[-1] in mult:
        return int(float(t[:-1]) * mult[t[-1]])
    return int(float(t))


def register(sub) -> None:
    from ..transfer.methods import METHODS, PRESETS, TEXTURE_NETS

    p = sub.add_parser("transfer", help="transfer skin texture from a style face onto a content face")
    p.add_argument("content", help="content face image (identity kept)")
    p.add_argument("style", help="style face image (texture source)")
    p.add_argument("-o", "--output", required=True, help="output image (.png/.jpg); OUT.json gets the parameters")
    p.add_argument("--method", choices=METHODS, default="facetex")
    p.add_argument("--preset", choices=PRESETS, default="default")
    p.add_argument("--size", type=int, help="long edge of the working region in px (default: preset's)")
    p.add_argument("--iters", type=_iters, help="L-BFGS iterations per level, e.g. 100,100,100")
    p.add_argument("--texture-net", choices=TEXTURE_NETS, help="texture feature network (default effnet-lite0)")
    p.add_argument("--vgg19-weights", help="path of torchvision's vgg19-dcbb9e9d.pth (for --texture-net vgg19)")
    p.add_argument("--crop", choices=("face", "image"), help="work on a face crop (default) or the whole image")
    p.add_argument("--save-every", type=int, help="save OUT_step<N>.png every N loss evaluations")
    p.add_argument("--max-memory", type=_memory, help="refuse above this estimated peak (e.g. 8G; default 75%% of free RAM)")
    add_seed_device(p)
    add_overwrite(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..io import check_output_path, read_image, write_image, write_json
    from ..transfer import transfer_with_info

    out = check_output_path(args.output, overwrite=args.overwrite)
    content = read_image(args.content)
    style = read_image(args.style)
    options = {k: v for k, v in {"size": args.size, "iters": args.iters, "texture_net": args.texture_net,
                                  "vgg19_weights": args.vgg19_weights, "crop": args.crop}.items() if v is not None}
    stem = Path(out).with_suffix("")

    def save(image, level, evaluation):
        if args.save_every:
            write_image(f"{stem}_level{level}_eval{evaluation:04d}.png", image)

    from ..transfer import preset

    params = preset(args.method, args.preset, args.texture_net).with_options(
        **{k: v for k, v in options.items() if k != "texture_net"})
    total = sum(params.iters) * 5 // 4 + params.levels  # L-BFGS evaluations are at most 1.25 × iterations
    with warnings.catch_warnings(record=True) as caught, progress_bar(total, desc=f"{args.method}", unit="eval") as bar:
        warnings.simplefilter("always")
        t0 = time.perf_counter()
        image, info = transfer_with_info(
            content, style, method=args.method, preset=args.preset, seed=args.seed, device=args.device,
            progress=lambda n=1, level=0, loss=0.0: bar(n, level=level, loss=f"{loss:.4g}"),
            callback=save if args.save_every else None, save_every=args.save_every,
            content_source=args.content, style_source=args.style, max_memory=args.max_memory, **options)
    for w in caught:
        print(f"facetex: warning: {w.message}", file=sys.stderr)
    info.pop("images", None)
    info["inputs"] = {"content": str(args.content), "style": str(args.style)}
    info["timings"]["wall_s"] = time.perf_counter() - t0
    write_image(out, image, overwrite=True)
    write_json(f"{out}.json", info, overwrite=True)
    print(f"wrote {out} ({info['timings']['total_s']:.1f} s) and {out}.json")
    return 0
