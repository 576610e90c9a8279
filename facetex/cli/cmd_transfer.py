"""``facetex transfer CONTENT STYLE -o OUT`` — FaceTex texture transfer (or a baseline)."""

from __future__ import annotations

import argparse
import math
import time
import warnings
from pathlib import Path

from ._common import add_overwrite, add_seed_device, bounded_int, check_device, positive_int, progress_bar

MAX_ITERS = 100_000  # per level
MAX_LEVELS = 8


def _iters(text: str) -> tuple[int, ...]:
    """argparse type of ``--iters``: comma-separated positive iteration counts, one per level."""
    try:
        vals = tuple(int(v) for v in str(text).split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"takes comma-separated integers such as 100,100,100, not {text!r}") from None
    if any(v < 1 for v in vals):
        raise argparse.ArgumentTypeError(f"every level needs at least 1 iteration, not {text!r}")
    if any(v > MAX_ITERS for v in vals) or len(vals) > MAX_LEVELS:
        raise argparse.ArgumentTypeError(f"at most {MAX_LEVELS} levels of at most {MAX_ITERS} iterations, "
                                         f"not {text!r}")
    return vals


_iters.__name__ = "iteration list"


def _memory(text: str) -> int:
    """argparse type of ``--max-memory``: a positive finite size such as 8G, 512M or 2000000000."""
    t = text.strip().upper()
    mult = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
    if t and t[-1] == "B":
        t = t[:-1]
    scale = 1
    if t and t[-1] in mult:
        t, scale = t[:-1], mult[t[-1]]
    try:
        v = float(t) * scale
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a size such as 8G or 512M, not {text!r}") from None
    if not math.isfinite(v) or v < 1:
        raise argparse.ArgumentTypeError(f"must be a positive, finite size such as 8G, not {text!r}")
    return int(v)


_memory.__name__ = "size"


def register(sub) -> None:
    from ..transfer.methods import METHODS, PRESETS, TEXTURE_NETS

    p = sub.add_parser("transfer", help="transfer skin texture from a style face onto a content face")
    p.add_argument("content", help="content face image (identity kept)")
    p.add_argument("style", help="style face image (texture source)")
    p.add_argument("-o", "--output", required=True, help="output image (.png/.jpg); OUT.json gets the parameters")
    p.add_argument("--method", choices=METHODS, default="facetex")
    p.add_argument("--preset", choices=PRESETS, default="default")
    p.add_argument("--size", type=bounded_int(32, 4096), help="long edge of the working region in px, 32..4096 "
                                                              "(default: preset's)")
    p.add_argument("--iters", type=_iters, help="L-BFGS iterations per level, e.g. 100,100,100")
    p.add_argument("--texture-net", choices=TEXTURE_NETS, help="texture feature network (default effnet-lite0)")
    p.add_argument("--vgg19-weights", help="path of torchvision's vgg19-dcbb9e9d.pth (for --texture-net vgg19)")
    p.add_argument("--crop", choices=("face", "image"), help="work on a face crop (default) or the whole image")
    p.add_argument("--save-every", type=positive_int,
                   help="save OUT_level<L>_eval<N>.png every N loss evaluations (kept if the run is interrupted)")
    p.add_argument("--max-memory", type=_memory, help="refuse above this estimated peak (e.g. 8G; default 75%% of free RAM)")
    add_seed_device(p)
    add_overwrite(p)
    p.set_defaults(func=run)


def check_step_files(stem: Path, overwrite: bool) -> None:
    """Refuse (before the work) when step files of an earlier run would be mixed with this one's."""
    from ..errors import OutputError

    old = sorted(stem.parent.glob(f"{stem.name}_level*_eval*.png"))
    if old and not overwrite:
        raise OutputError(f"{len(old)} step file(s) of an earlier run exist (e.g. {old[0].name}): remove them "
                          "or pass --overwrite to replace them", path=old[0])


def run(args) -> int:
    from ..io import IMAGE_EXTENSIONS, check_input_file, check_output_path, encode_image, encode_json, read_image
    from ..io import write_files, write_image
    from ..transfer import preset, transfer_with_info

    inputs = [args.content, args.style] + ([args.vgg19_weights] if args.vgg19_weights else [])
    # everything that can be checked is checked before the work
    out = check_output_path(args.output, overwrite=args.overwrite, inputs=inputs, extensions=IMAGE_EXTENSIONS,
                            what="image")
    sidecar = check_output_path(f"{out}.json", overwrite=args.overwrite, inputs=inputs)
    stem = Path(out).with_suffix("")
    if args.save_every:
        check_step_files(stem, args.overwrite)
    for p in inputs:
        check_input_file(p)
    options = {k: v for k, v in {"size": args.size, "iters": args.iters, "texture_net": args.texture_net,
                                  "vgg19_weights": args.vgg19_weights, "crop": args.crop}.items() if v is not None}
    params = preset(args.method, args.preset, args.texture_net).with_options(
        **{k: v for k, v in options.items() if k != "texture_net"})
    check_device(args.device)
    content = read_image(args.content)
    style = read_image(args.style)

    def save(image, level, evaluation):
        write_image(f"{stem}_level{level}_eval{evaluation:04d}.png", image, overwrite=args.overwrite, inputs=inputs)

    total = sum(params.iters) * 5 // 4 + params.levels  # L-BFGS evaluations are at most 1.25 × iterations
    with warnings.catch_warnings(), progress_bar(total, desc=f"{args.method}", unit="eval") as bar:
        warnings.simplefilter("always")  # advice (e.g. upscaling) is shown when it is known, before the work
        t0 = time.perf_counter()
        image, info = transfer_with_info(
            content, style, method=args.method, preset=args.preset, seed=args.seed, device=args.device,
            progress=lambda n=1, level=0, loss=0.0: bar(n, level=level, loss=f"{loss:.4g}"),
            callback=save if args.save_every else None, save_every=args.save_every,
            content_source=args.content, style_source=args.style, max_memory=args.max_memory, **options)
    info.pop("images", None)
    info["inputs"] = {"content": str(args.content), "style": str(args.style)}
    info["timings"]["wall_s"] = time.perf_counter() - t0
    # the image and its sidecar are committed together: never one without the other
    write_files({out: encode_image(out, image), sidecar: encode_json(info)}, overwrite=args.overwrite,
                inputs=inputs)
    print(f"wrote {out} ({info['timings']['total_s']:.1f} s) and {sidecar}")
    return 0
