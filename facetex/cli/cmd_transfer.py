"""``facetex transfer CONTENT STYLE -o OUT`` — FaceTex texture transfer (or a baseline).

Options follow neural-style-pt's conventions where they overlap: loss weights on the
command line, ``--init``, ``--print-every``, ``--save-every``, ``-q/--quiet``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from pathlib import Path

from ._common import (add_json, add_output, add_overwrite, add_quiet, add_seed_device, bounded_int, check_device,
                      finite_float, nonnegative_int, positive_int, progress_bar, wrote)

MAX_ITERS = 100_000  # per level
MAX_LEVELS = 8

METHOD_HELP = {"facetex": "FaceTex (Eq. 5: MRF texture + facial structure + TV, skin only)",
               "mrf": "MRF-CNN baseline (Eq. 7)", "gatys": "Gatys neural style baseline (Eq. 6)"}
PRESET_HELP = {"default": "384 px face crop, up to 3 x 100 L-BFGS iterations (a level ends when its loss stops "
                          "falling), seconds on a CPU",
               "paper": "the paper's whole image at 1000 px, 3 x 200 iterations (much slower)",
               "preview": "the default's steps at 256 px and 3 x 12 iterations: seconds, to choose a style"}


def _iters(text: str) -> tuple[int, ...]:
    """argparse type of ``--iters``: comma-separated positive iteration counts, one per level."""
    from .._api import parse_iters
    from ..errors import BadInputError

    try:
        return parse_iters(text)
    except BadInputError as e:
        raise argparse.ArgumentTypeError(str(e).replace("iters takes", "takes")) from None


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


def _choices_help(table: dict, default: str) -> str:
    return "; ".join(f"{k}{' (default)' if k == default else ''}: {v}" for k, v in table.items())


def register(sub) -> None:
    from ..transfer.methods import METHODS, PRESETS, TEXTURE_NETS

    p = sub.add_parser(
        "transfer", help="transfer skin texture from a style face onto a content face",
        description="Transfer the skin texture of STYLE onto CONTENT, keeping the content person's identity "
                    "(FaceTex, Kaur, Zhang & Dana 2017), or run a baseline. Writes OUT and OUT.json (every "
                    "parameter, input hashes, versions, timings).")
    p.add_argument("content", help="content face image (identity kept)")
    p.add_argument("style", help="style face image (texture source)")
    add_output(p, required=True, metavar="OUT",
                   help="output image (.png/.jpg/.tif/.webp); OUT.json gets the parameters")
    p.add_argument("--method", choices=METHODS, default="facetex", help=_choices_help(METHOD_HELP, "facetex"))
    p.add_argument("--preset", choices=PRESETS, default="default", help=_choices_help(PRESET_HELP, "default"))
    p.add_argument("--size", type=bounded_int(32, 4096), metavar="PX",
                   help="long edge of the working region in px, 32..4096 (default: the preset's, 384 / 1000)")
    p.add_argument("--iters", type=_iters, metavar="N,N,N",
                   help="L-BFGS iterations per resolution level, e.g. 100,100,100 (default: the preset's)")
    p.add_argument("--init", default="content", metavar="content|random|PATH",
                   help="start of the optimisation: the content image (default), seeded uniform noise, or an "
                        "image file of the content's size")
    w = p.add_argument_group("loss weights (default: the method's; normalised per level, see the README)")
    for name, what in (("mrf", "MRF texture term (Eq. 2)"), ("structure", "facial-structure term (Eq. 3)"),
                       ("content", "content term (Eqs. 6, 7)"), ("style", "Gram style term (Eq. 6)"),
                       ("tv", "total-variation term (Eq. 4)")):
        w.add_argument(f"--{name}-weight", type=finite_float(0.0), metavar="W", help=f"weight of the {what}")
    p.add_argument("--texture-net", choices=TEXTURE_NETS,
                   help="texture feature network (default effnet-lite0; vgg19 needs --vgg19-weights or the "
                        "torchvision file in $TORCH_HOME)")
    p.add_argument("--vgg19-weights", metavar="PATH", help="path of torchvision's vgg19-dcbb9e9d.pth (for --texture-net vgg19)")
    p.add_argument("--crop", choices=("face", "image"), help="work on a face crop (default preset) or the whole image")
    p.add_argument("--keep-shading", choices=("on", "off"),
                   help="on (default preset): the content keeps its own low-frequency skin colour and shading, the "
                        "style brings only detail; off: the style's shading and colour cast come too")
    p.add_argument("--marks", choices=("content", "style", "off"),
                   help="moles and spots: keep the content's (default preset), bring the style's, or off "
                        "(no marks step)")
    p.add_argument("--save-every", type=positive_int, metavar="N",
                   help="every N loss evaluations (and after each level) write the full-size image so far as "
                        "OUT_level<L>_eval<NNNN>.png beside OUT (kept if the run is interrupted)")
    p.add_argument("--print-every", type=nonnegative_int, default=0, metavar="N",
                   help="print the loss terms every N loss evaluations (default 0: never)")
    p.add_argument("--max-memory", type=_memory, metavar="SIZE",
                   help="refuse above this estimated peak (e.g. 8G; default 75%% of free RAM)")
    add_seed_device(p)
    add_overwrite(p)
    add_quiet(p)
    add_json(p, "the written files, seed and timings")
    p.set_defaults(func=run)


def check_step_files(stem: Path, overwrite: bool) -> None:
    """Refuse (before the work) when step files of an earlier run would be mixed with this one's."""
    from ..errors import OutputError

    old = sorted(stem.parent.glob(f"{stem.name}_level*_eval*.png"))
    if old and not overwrite:
        raise OutputError(f"{len(old)} step file(s) of an earlier run exist (e.g. {old[0].name}): remove them "
                          "or pass --overwrite to replace them", path=old[0])


def run(args) -> int:
    from .._api import as_image, transfer_params, transfer_step_image
    from .._api import transfer_with_info
    from .._provenance import provenance
    from ..errors import BadInputError
    from ..io import (DETECT_MAX_PIXELS, IMAGE_EXTENSIONS, check_input_file, check_output_path, encode_image,
                      encode_json, read_image, to_uint8, write_files, write_image)
    from ..transfer import face_crop_box
    from ..transfer._regions import NATIVE_MAX_PIXELS, detect_points68

    init_path = None if args.init in ("content", "random") else args.init
    inputs = [args.content, args.style] + [p for p in (args.vgg19_weights, init_path) if p]
    # everything that can be checked is checked before the work
    out = check_output_path(args.output, overwrite=args.overwrite, inputs=inputs, extensions=IMAGE_EXTENSIONS,
                            what="image")
    sidecar = check_output_path(f"{out}.json", overwrite=args.overwrite, inputs=inputs)
    stem = Path(out).with_suffix("")
    if args.save_every:
        check_step_files(stem, args.overwrite)
    for p in inputs:
        check_input_file(p)
    weights = {f"{k}_weight": getattr(args, f"{k}_weight") for k in ("mrf", "structure", "content", "style", "tv")}
    options = {k: v for k, v in {"size": args.size, "iters": args.iters, "texture_net": args.texture_net,
                                  "vgg19_weights": args.vgg19_weights, "crop": args.crop, **weights,
                                  "keep_shading": None if args.keep_shading is None else args.keep_shading == "on",
                                  "marks": args.marks}.items()
               if v is not None}
    params = transfer_params(args.method, args.preset, **options)
    check_device(args.device)
    content = read_image(args.content)
    if content.shape[0] * content.shape[1] > NATIVE_MAX_PIXELS:
        content = to_uint8(content)  # worked on reduced (transfer_with_info): kept as 8-bit, 1/4 of float
    style = read_image(args.style, reduce_to=DETECT_MAX_PIXELS)  # only its face's texture is used
    init = args.init
    if init_path:
        init = as_image(init_path, f"--init image {init_path}")
        if init.shape != content.shape:
            raise BadInputError(f"--init image is {init.shape[1]}x{init.shape[0]} px, the content "
                                f"{content.shape[1]}x{content.shape[0]}: it must have the content's size",
                                path=init_path)
    points_c = detect_points68(content, args.content)  # on a copy reduced to 8 MP when larger
    points_s = detect_points68(style, args.style)
    box = face_crop_box(points_c, content.shape) if params.crop == "face" else (0, 0, content.shape[1],
                                                                                content.shape[0])
    steps: list[str] = []

    def save(image, level, evaluation, full_image=None, **_):
        path = f"{stem}_level{level}_eval{evaluation:04d}.png"
        mine = path in steps  # the end of a level can fall on a periodic save: same name, same run
        full = full_image if full_image is not None else transfer_step_image(content, image, box)
        write_image(path, full, overwrite=args.overwrite or mine, inputs=inputs)
        if not mine:
            steps.append(path)
            if not (args.quiet or args.json):
                from tqdm import tqdm

                tqdm.write(f"wrote {path}", file=sys.stdout)

    total = int(sum(params.iters) * params.eval_budget) + params.levels  # the evaluation budget per level
    evals = 0
    with warnings.catch_warnings(), progress_bar(total, desc=args.method, unit="eval", disable=args.quiet) as bar:
        warnings.simplefilter("always")  # advice (e.g. upscaling) is shown when it is known, before the work

        def progress(n=1, level=0, loss=0.0, terms=None, **_):
            nonlocal evals
            evals += n
            bar(n, level=level, loss=f"{loss:.4g}")
            if args.print_every and evals % args.print_every == 0 and not args.quiet:
                from tqdm import tqdm

                parts = "".join(f", {k} {v:.4g}" for k, v in (terms or {}).items())
                tqdm.write(f"level {level} evaluation {evals}: loss {loss:.6g}{parts}", file=sys.stderr)

        t0 = time.perf_counter()
        image, info = transfer_with_info(
            content, style, method=args.method, preset=args.preset, seed=args.seed, device=args.device,
            progress=progress, callback=save if args.save_every else None, save_every=args.save_every,
            content_points=points_c, style_points=points_s, content_source=args.content,
            style_source=args.style, max_memory=args.max_memory, init=init, **options)
    info.pop("images", None)
    content = style = init = None  # a 36 MP image is 0.4 GB as float: neither input nor the float
    image = to_uint8(image)  # output is kept beside the encoding (the file is 8-bit: the same bytes)
    info["timings"]["wall_s"] = time.perf_counter() - t0
    record = provenance(
        command="transfer", seed=args.seed,
        inputs={"content": args.content, "style": args.style, "init": init_path, "vgg19_weights": args.vgg19_weights},
        params={**(info.get("params") or {}), "method": args.method, "preset": args.preset, "init": args.init,
                "device": args.device, "command_line_options": options},
        outputs=[out], steps=steps, result=info)
    # the image and its sidecar are committed together: never one without the other
    write_files({out: encode_image(out, image), sidecar: encode_json(record)}, overwrite=args.overwrite,
                inputs=inputs)
    wrote(args, out, sidecar, steps=steps, seed=args.seed, timings_s=info["timings"])  # steps: each said when written
    return 0
