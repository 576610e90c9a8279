"""``facetex puppet --driver VIDEO --puppet PERSON.persona -o OUT.mp4`` — persona puppetry (Tom Hanks §4, §6)."""

from __future__ import annotations

import sys

from ._common import (add_json, add_output, add_overwrite, add_quiet, bounded_int, finite_float, positive_int,
                      print_json, progress_bar, wrote)

MAX_SIZE = 4096  # longer side of an output panel (px)


def register(sub) -> None:
    p = sub.add_parser("puppet", help="drive a persona's 3D face with another person's video")
    # positionals as in the other commands; --driver/--puppet are the older spelling, kept
    p.add_argument("driver_pos", nargs="?", metavar="DRIVER", help="driver video (MP4/MOV/MKV/AVI/MPG) showing one face")
    p.add_argument("puppet_pos", nargs="?", metavar="PUPPET", help="puppet .persona file (facetex persona build)")
    p.add_argument("--driver", help="the same as DRIVER")
    p.add_argument("--puppet", help="the same as PUPPET")
    add_output(p, required=True, metavar="OUT.mp4", help="output H.264 .mp4 (the driver's audio is kept)")
    p.add_argument("--driver-photos", help="folder of photos of the driver for its average shape "
                                           "(default: the video's frames)")
    p.add_argument("--side-by-side", action="store_true", help="put the driver frame left of the puppet")
    p.add_argument("--size", type=bounded_int(32, MAX_SIZE),
                   help=f"longer side of the output frame (per panel) in px, 32..{MAX_SIZE} (default: the driver's)")
    p.add_argument("--mode", choices=("composite", "face"), default="composite",
                   help="composite: the puppet put into the driver's frame (its lighting, colour and face "
                        "outline; default); face: the puppet face alone on plain grey, as in the paper's figures")
    p.add_argument("--lighting", choices=("stats", "sh", "none"), default="stats",
                   help="composite mode: match the driver's skin colour statistics (default), also its "
                        "first-order spherical-harmonics lighting (sh), or neither (none)")
    p.add_argument("--colour", choices=("driver", "persona"), default="driver",
                   help="composite mode: the puppet takes the driver's skin colour and lighting (default), or keeps "
                        "the persona's skin tone and takes only the driver's lighting (persona)")
    p.add_argument("--sharpen", type=finite_float(1.0, 4.0), default=2.5, metavar="GAIN",
                   help="composite mode: raise the puppet's fine detail towards the driver frame's, at most by "
                        "this gain, its skin and its features (eyes, brows, lips, nostrils) each to the driver's "
                        "(default 2.5; 1 = off; 1..4)")
    p.add_argument("--grain", type=finite_float(0.0, 1.0), default=1.0, metavar="AMOUNT",
                   help="composite mode: where the puppet is still smoother than the driver's frame, add the "
                        "frame's own fine grain on the skin (on a large frame, also its skin texture a few pixels "
                        "across, finer than the persona's photos), at most at this strength (default 1; 0 = off)")
    p.add_argument("--nose-sharpen", type=finite_float(1.0, 4.0), default=3.0, metavar="GAIN",
                   help="composite mode: then raise the puppet's lower nose (nostrils, its shaded sides) towards the "
                        "driver's nose's fine detail, at most by this further gain (default 3; 1 = off; 1..4)")
    p.add_argument("--eyes", choices=("driver", "persona"), default="driver",
                   help="composite mode: the driver's eyeballs (whites, lash line, gaze) inside the puppet's lids "
                        "with the persona's iris colour (default), or the persona's texture's own eyes (persona)")
    p.add_argument("--occlusion", choices=("on", "off"), default="on",
                   help="composite mode: keep what lies over the driver's face in front of the puppet: a fringe, "
                        "a hand, the rims of its glasses (default on)")
    p.add_argument("--persona-hair", choices=("on", "off"), default="on",
                   help="composite mode: where the persona's own hair lies over its forehead or temples (in most "
                        "of its photos), show the driver's frame instead (default on)")
    p.add_argument("--texture", choices=("ours", "static"), default="ours",
                   help="expression-dependent texture (default) or the static average texture")
    p.add_argument("--weights", choices=("regional", "global"), default="regional",
                   help="expression weights of the texture: regional (default; mouth, eyes and the rest of the "
                        "face each weighted by their own fiducials, as `persona texture`) or global (the paper's "
                        "Eq. 2/3, sigma 10)")
    p.add_argument("--correspondence", choices=("landmarks", "flow"), default="landmarks",
                   help="driver-to-puppet correspondence of the deformation transfer: landmarks (default; a "
                        "thin-plate spline between the two mean landmark sets) or flow (the paper's optical flow "
                        "from the puppet's projection onto the driver's appearance subspace)")
    p.add_argument("--weight-smoothing", type=finite_float(0.0, 10.0), default=0.12,
                   metavar="SECONDS",
                   help="regional weights made temporally coherent over this many seconds (a bilateral filter over "
                        "frames and expression: a still face does not shimmer, a mouth opening is kept; default "
                        "%(default)s; 0 = per frame)")
    p.add_argument("--max-frames", type=positive_int, help="use only the first N frames")
    add_overwrite(p)
    add_quiet(p)
    add_json(p, "the run's report (frames, lost frames, timings)")
    p.set_defaults(func=run)


def _merge_positionals(args) -> None:
    """``DRIVER PUPPET`` or ``--driver/--puppet`` (not both, not neither) into ``args.driver``/``args.puppet``."""
    from ..errors import BadInputError

    for name in ("driver", "puppet"):
        pos, opt = getattr(args, f"{name}_pos"), getattr(args, name)
        if pos is not None and opt is not None and pos != opt:
            raise BadInputError(f"two {name}s given ({pos} and --{name} {opt}): give one")
        if pos is None and opt is None:
            raise BadInputError(f"no {name} given: facetex puppet DRIVER PUPPET -o OUT.mp4")
        setattr(args, name, opt if opt is not None else pos)


def run(args) -> int:
    _merge_positionals(args)
    # the driver's tracking starts first, in a child process: this one then checks the arguments,
    # imports the puppet code and loads the persona beside it (nothing is written before the checks)
    tracker = _start_tracking(args)
    _single_threaded_blas()
    loading = _start_loading(args)
    try:
        return _run(args, tracker, loading)
    finally:
        tracker.cancel()  # a no-op once its result was taken


def _single_threaded_blas() -> None:
    """BLAS on one thread in this process (before numpy loads it): the puppetry runs its own
    threads (persona stacks, frames), and BLAS's threads on its small matrices (Procrustes SVDs,
    splines) cost more than they save: the driver motion took 0.18 s of CPU alone on one BLAS
    thread, 0.54 s on two (2.2 s of wall time on a shared 2-core machine). ``OMP_NUM_THREADS``
    stays the thread budget of facetex's own pools."""
    import os

    if "numpy" not in sys.modules:
        os.environ.update(OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")


def _puppet_params(args):
    from ..puppet.composite import CompositeParams
    from ..puppet.puppetry import PuppetParams

    return PuppetParams(texture=args.texture, weights=args.weights, correspondence=args.correspondence,
                        weight_smoothing=args.weight_smoothing,
                        composite=CompositeParams(lighting=args.lighting, colour=args.colour, sharpen=args.sharpen,
                                                  grain=args.grain, nose_sharpen=args.nose_sharpen, eyes=args.eyes,
                                                  occlusion=args.occlusion == "on",
                                                  persona_hair=args.persona_hair == "on"))


def _start_loading(args):
    """The persona's load and precomputation (:func:`~facetex.puppet.puppetry.load_puppet`) on a
    thread, beside this one's checks and imports (~1 s; the load and the texture stacks are mostly
    zlib, OpenCV and numpy, which release the GIL): a future. A daemon thread: an error in the
    arguments ends the command without waiting for it."""
    import threading
    from concurrent.futures import Future

    from .._parallel import serialize_ast_parse

    serialize_ast_parse()  # numpy's .npy headers and inspect parse Python on both threads
    fut = Future()

    def work():
        if not fut.set_running_or_notify_cancel():
            return
        try:
            from ..puppet.puppetry import load_puppet

            fut.set_result(load_puppet(args.puppet, _puppet_params(args)))
        except BaseException as e:  # noqa: BLE001 - handed to the puppetry, which re-raises it
            fut.set_exception(e)

    threading.Thread(target=work, name="facetex-persona-load", daemon=True).start()
    return fut


def _run(args, tracker, loading=None) -> int:
    from ..errors import BadInputError
    from ..io import VIDEO_EXTENSIONS, check_input_dir, check_output_path, video_info
    from ..persona import read_persona_header

    # everything checked before the work: output, inputs, the driver's size
    inputs = [args.driver, args.puppet]
    out = check_output_path(args.output, overwrite=args.overwrite, inputs=inputs, extensions=VIDEO_EXTENSIONS,
                            what="video")
    sidecar = check_output_path(f"{out}.json", overwrite=args.overwrite, inputs=inputs)
    if args.driver_photos:
        check_input_dir(args.driver_photos, BadInputError, what="driver photo folder")
    read_persona_header(args.puppet)  # fail fast on a wrong file; the arrays load while the driver is tracked
    info = video_info(args.driver)
    n = info["n_frames"]
    if args.size is not None:  # an output frame too large to render and encode within the memory budget
        from ..puppet.puppetry import check_output_frame

        check_output_frame((info["width"], info["height"]), args.size, side_by_side=args.side_by_side,
                           mode=args.mode, path=args.driver)
    if args.max_frames is not None:
        n = min(n, max(0, args.max_frames))
    from .._provenance import hash_in_background, provenance
    from ..io import write_json

    hashing = hash_in_background(inputs)  # beside the setup, not after the rendering
    from ..puppet.puppetry import puppeteer

    params = _puppet_params(args)
    with progress_bar(2 * n, desc="puppet", unit="frame", disable=args.quiet) as bar:
        report = puppeteer(args.driver, args.puppet, args.output, driver_photos=args.driver_photos,
                           side_by_side=args.side_by_side, size=args.size, mode=args.mode,
                           overwrite=args.overwrite, max_frames=args.max_frames, params=params, progress=bar,
                           tracking=tracker, loading=loading)
    hashing.join()
    write_json(sidecar, provenance(
        command="puppet", inputs={"driver": args.driver, "puppet": args.puppet, "driver_photos": args.driver_photos},
        params={"side_by_side": args.side_by_side, "size": args.size, "mode": args.mode, "texture": args.texture,
                "weights": args.weights, "weight_smoothing": args.weight_smoothing,
                "correspondence": args.correspondence, "lighting": args.lighting, "colour": args.colour,
                "sharpen": args.sharpen, "grain": args.grain, "nose_sharpen": args.nose_sharpen, "eyes": args.eyes,
                "occlusion": args.occlusion, "persona_hair": args.persona_hair,
                "max_frames": args.max_frames,
                "puppet_params": params},
        outputs=[out], result=report), overwrite=args.overwrite, inputs=inputs)
    if report["lost_frames"] and not args.quiet:
        print(f"{args.driver}: face lost in {report['lost_frames']} of {report['frames']} frames "
              "(not found, partly outside the frame or implausible; those frames show the driver)", file=sys.stderr)
    if args.json:
        print_json(report)
    else:
        wrote(args, out, sidecar)
    return 0


def _start_tracking(args):
    """The driver's tracking in a child process, with the parameters
    :func:`~facetex.puppet.puppetry.prepare_puppetry` derives (it checks them): the default
    DriverParams in the persona's canonical frame (read by the child: nothing heavy is imported
    here)."""
    from ..puppet._tracking import DriverTracking

    return DriverTracking(args.driver, size_of=args.puppet, max_frames=args.max_frames, params=None,
                          frontal_images=args.driver_photos is None and args.correspondence == "flow")
