"""``facetex persona build|texture|average|mesh`` — persona textures and average 3D face from a photo
collection (Tom Hanks Sec. 4-5)."""

from __future__ import annotations

from ._common import (add_jobs, add_json, add_output, add_overwrite, add_quiet, bounded_int, finite_float,
                      positive_int, print_json, progress_bar, wrote)


def register(sub) -> None:
    p = sub.add_parser("persona", help="build a persona from photos of one person; synthesize its textures")
    ps = p.add_subparsers(dest="persona_command", metavar="ACTION")
    ps.required = True

    b = ps.add_parser("build", help="detect, frontalize and align a folder of photos into a .persona file")
    b.add_argument("photo_dir", metavar="PHOTO_DIR", help="folder of photos of one person (>= 10 usable)")
    add_output(b, required=True, metavar="PERSON.persona", help="persona file to write")
    add_jobs(b, "worker processes")
    b.add_argument("--min-photos", type=bounded_int(3), default=10, metavar="N",
                   help="fewest usable photos accepted (default 10)")
    b.add_argument("--allow-mixed", action="store_true",
                   help="build even when the photos show several people (default: photos of other people are "
                        "left out when one person has >= 80%% of them, else the build is refused)")
    b.add_argument("--no-texture-stacks", action="store_true",
                   help="do not store the texture synthesis's precomputed stacks (~0.5 MB per photo): a smaller "
                        "file; puppetry and texture synthesis then compute them when they start (~10 ms per photo)")
    add_overwrite(b)
    add_quiet(b)
    add_json(b, "the written files and the build's summary")
    b.set_defaults(func=run_build)

    t = ps.add_parser("texture", help="synthesize a texture for a target expression")
    t.add_argument("persona", metavar="PERSON.persona")
    g = t.add_mutually_exclusive_group(required=True)
    g.add_argument("--like", metavar="REF_IMAGE", help="reference photo giving the target expression")
    g.add_argument("--fiducials", metavar="POINTS.json",
                   help='target fiducials in the canonical frame: a JSON list of 49 (or 68) [x, y] '
                        'or {"fiducials": [...]}')
    add_output(t, required=True, metavar="OUT.png", help="texture image to write (+ .json sidecar)")
    t.add_argument("--method", choices=("ours", "static", "weighted", "prewarp"), default="ours",
                   help="ours (default) or a Fig. 5 baseline")
    t.add_argument("--weights", choices=("regional", "global"), default="regional",
                   help="expression weights: regional (default: mouth, eyes and the rest of the face each "
                        "weighted by their own fiducials) or global (the paper's Eq. 2/3: all fiducials, sigma, "
                        "Laplacian weighting alpha 1)")
    t.add_argument("--sigma", type=finite_float(0.0, open_lo=True), default=None,
                   help="--weights global only: sigma of Eq. 2/3 (default 10, typically 6-12)")
    t.add_argument("--neighbours", type=positive_int, default=None, metavar="K",
                   help="--weights regional only: each region's sigma is the target's distance to its K-th "
                        "nearest photo / 2 (default 3)")
    add_overwrite(t)
    add_quiet(t)
    add_json(t, "the written files")
    t.set_defaults(func=run_texture)

    a = ps.add_parser("average", help="the persona's average face (Fig. 6 stages a-d)")
    a.add_argument("persona", metavar="PERSON.persona")
    add_output(a, required=True, metavar="OUT.png", help="average image to write (+ .json sidecar)")
    a.add_argument("--stage", choices=("a", "b", "c", "d"), default="d",
                   help="a: frontalized, b: + TPS, c: + dense warp, d: + multi-scale blend (default)")
    add_overwrite(a)
    add_quiet(a)
    add_json(a, "the written files")
    a.set_defaults(func=run_average)

    m = ps.add_parser("mesh", help="the persona's average 3D face as an .obj (+ .mtl, .png texture)")
    m.add_argument("persona", metavar="PERSON.persona")
    add_output(m, required=True, metavar="FACE.obj",
                   help="mesh to write; FACE.mtl and FACE.png (stage-d average texture) go beside it")
    m.add_argument("--step", type=positive_int, default=1, metavar="N",
                   help="grid step of the mesh in canonical px (default 1; at most 1/8 of the frame width)")
    m.add_argument("--shape", choices=("collection", "generic"), default="collection",
                   help="collection: the persona's photometric-stereo average depth when it passed its "
                        "photometric validation on held-out photos (default; else the generic face, and the "
                        "report says why); generic: the generic face")
    add_overwrite(m)
    add_json(m, "the mesh's summary (vertices, faces, depth source, paths)")
    m.set_defaults(func=run_mesh)


def _outputs(args, inputs) -> tuple:
    """OUT.png and its sidecar OUT.png.json, checked before the work (both or neither are written)."""
    from ..io import IMAGE_EXTENSIONS, check_output_path

    out = check_output_path(args.output, overwrite=args.overwrite, inputs=inputs, extensions=IMAGE_EXTENSIONS,
                            what="image")
    return out, check_output_path(f"{out}.json", overwrite=args.overwrite, inputs=inputs)


def _write_with_sidecar(out, sidecar, image, record: dict, args, inputs) -> None:
    from ..io import encode_image, encode_json, write_files

    write_files({out: encode_image(out, image), sidecar: encode_json(record)}, overwrite=args.overwrite,
                inputs=inputs)
    wrote(args, out, sidecar)


def run_build(args) -> int:
    import sys
    import time

    from ..errors import BadInputError
    from ..io import check_input_dir, check_output_path
    from ..persona import PersonaParams, build_persona
    from ..persona.build import _list_photos
    from ..persona.build import SHAPE_STEPS
    from ..persona.identity import MixedCollectionError
    from ._common import jobs_of

    from .._provenance import provenance
    from ..io import encode_json, write_files

    folder = check_input_dir(args.photo_dir, BadInputError, what="photo folder")
    photos = _list_photos(folder)
    out = check_output_path(args.output, overwrite=args.overwrite, inputs=photos, extensions=(".persona",),
                            what="persona file")
    sidecar = check_output_path(f"{out}.json", overwrite=args.overwrite, inputs=photos)
    t0 = time.perf_counter()
    stacks = not args.no_texture_stacks
    # two passes over the photos, the shape's steps, then the texture stacks made while saving
    total = 2 * len(photos) + SHAPE_STEPS + int(stacks)
    with progress_bar(total=total, desc="persona", unit="step", disable=args.quiet) as update:
        try:
            persona = build_persona(folder, jobs=jobs_of(args), progress=update, allow_mixed=args.allow_mixed,
                                    params=PersonaParams(min_photos=args.min_photos))
        except MixedCollectionError as e:
            raise MixedCollectionError(f"{e.message}, or pass --allow-mixed to build from all of them",
                                       path=e.path, main=e.main, others=e.others, people=e.people) from None
        record = provenance(command="persona build", inputs={"photo_dir": folder},
                            params={"jobs": jobs_of(args), "min_photos": args.min_photos,
                                    "allow_mixed": args.allow_mixed, "texture_stacks": stacks,
                                    "persona_params": persona.params},
                            outputs=[out], photos_used=len(persona), skipped=persona.skipped,
                            seconds=time.perf_counter() - t0)
        if stacks:
            update(n=0, stage="texture stacks")
        # the persona and its sidecar are committed together
        write_files({out: lambda tmp: persona.save(tmp, overwrite=True, texture_stacks=stacks),
                     sidecar: encode_json(record)},
                    overwrite=args.overwrite, inputs=photos)
        if stacks:
            update(n=1, stage="saved")
    if not args.quiet:
        print(f"{out}: {len(persona)} photos used, {len(persona.skipped)} skipped "
              f"({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
        for s in persona.skipped:
            print(f"  skipped {s['file']}: {s['reason']}", file=sys.stderr)
    wrote(args, out, sidecar, photos_used=len(persona), skipped=persona.skipped,
          seconds=round(time.perf_counter() - t0, 2))
    return 0


def _read_fiducials(path, size=None):
    """Target fiducials (49 or 68 [x, y]) from a JSON file; finite and, given the persona's
    canonical ``size`` (W, H), inside that frame."""
    import numpy as np

    from ..errors import BadInputError
    from ..landmarks import POINTS49_INDEX
    from ._common import read_json_file

    obj = read_json_file(path, BadInputError, what="fiducials JSON file")
    if isinstance(obj, dict):
        obj = obj.get("fiducials", obj.get("points49", obj.get("points68")))
    try:
        a = np.asarray(obj, dtype=np.float64)
    except (TypeError, ValueError, OverflowError, RecursionError):
        a = np.empty(0)
    if a.shape not in ((49, 2), (68, 2)):
        raise BadInputError(f"fiducials must be 49 (or 68) [x, y] points, got shape {a.shape}", path=path)
    if not np.all(np.isfinite(a)):
        bad = int(np.flatnonzero(~np.isfinite(a).all(axis=1))[0])
        raise BadInputError(f"fiducials contain NaN or infinite values (point {bad}): give finite numbers",
                            path=path)
    if size is not None:
        W, H = size
        f = a[POINTS49_INDEX] if len(a) == 68 else a
        out = np.flatnonzero((f[:, 0] < 0) | (f[:, 0] > W - 1) | (f[:, 1] < 0) | (f[:, 1] > H - 1))
        if len(out):
            k = int(out[0])
            raise BadInputError(f"{len(out)} fiducials lie outside the persona's {W}x{H} canonical frame (point "
                                f"{k} at ({f[k, 0]:.4g}, {f[k, 1]:.4g})): give points in canonical-frame pixels",
                                path=path)
        span = float(np.ptp(f, axis=0).min())
        if span < 0.1 * min(W, H):
            raise BadInputError(f"fiducials are degenerate (they span only {span:.3g} px): give a face's "
                                "49 points in canonical-frame pixels", path=path)
    return a


def _texture_params(args):
    """TextureParams of ``persona texture``'s options, checked before any work."""
    from .._api import texture_params
    from ..errors import BadInputError

    if args.sigma is not None and args.weights != "global":
        raise BadInputError("--sigma applies to --weights global (the regional weights measure their own "
                            "sigma: use --neighbours)")
    if args.neighbours is not None and args.weights != "regional":
        raise BadInputError("--neighbours applies to --weights regional (the global weights take --sigma)")
    return texture_params(weights=args.weights, sigma=args.sigma, neighbours=args.neighbours)


def run_texture(args) -> int:
    import time

    from ..errors import BadImageError
    from ..io import check_input_file
    from ..persona import load_persona, read_persona_header, synthesize_texture

    tp = _texture_params(args)
    inputs = [args.persona, args.like or args.fiducials]
    out, sidecar = _outputs(args, inputs)
    t0 = time.perf_counter()
    size = read_persona_header(args.persona)["size"]
    if args.like:
        check_input_file(args.like, BadImageError, what="image file")
        kw = {"reference": args.like}
    else:
        kw = {"fiducials": _read_fiducials(args.fiducials, size)}
    persona = load_persona(args.persona)
    t1 = time.perf_counter()
    with progress_bar(desc="texture", unit="step", disable=args.quiet) as update:
        img = synthesize_texture(persona, method=args.method, params=tp, progress=update, **kw)
    t2 = time.perf_counter()
    from .._provenance import provenance

    _write_with_sidecar(out, sidecar, img, provenance(
        command="persona texture", inputs={"persona": args.persona, "like": args.like, "fiducials": args.fiducials},
        params={"method": args.method, "weights": tp.weights,
                "sigma": tp.sigma if tp.weights == "global" else None,
                "neighbours": tp.neighbours if tp.weights == "regional" else None,
                "target": "like" if args.like else "fiducials"},
        outputs=[out], photos=len(persona),
        timings_s={"load": t1 - t0, "synthesize_incl_precompute": t2 - t1}), args, inputs)
    return 0


def run_average(args) -> int:
    import time

    from ..persona import average_face, load_persona

    inputs = [args.persona]
    out, sidecar = _outputs(args, inputs)
    t0 = time.perf_counter()
    persona = load_persona(args.persona)
    t1 = time.perf_counter()
    img = average_face(persona, args.stage)
    t2 = time.perf_counter()
    from .._provenance import provenance

    _write_with_sidecar(out, sidecar, img, provenance(
        command="persona average", inputs={"persona": args.persona}, params={"stage": args.stage},
        outputs=[out], photos=len(persona), timings_s={"load": t1 - t0, "average": t2 - t1}), args, inputs)
    return 0


def run_mesh(args) -> int:
    import time
    from pathlib import Path

    from .._api import persona_mesh
    from .._provenance import provenance
    from ..errors import BadInputError, OutputError
    from ..io import check_output_path, encode_json
    from ..persona import load_persona, read_persona_header

    out = Path(args.output)
    if out.suffix.lower() != ".obj":
        raise OutputError("mesh file name must end in .obj", path=out)
    paths = {"obj": out, "mtl": out.with_suffix(".mtl"), "texture": out.with_suffix(".png"),
             "sidecar": Path(f"{out}.json")}
    for p in paths.values():  # before any work: no partial output set
        check_output_path(p, overwrite=args.overwrite, inputs=[args.persona])
    W, H = read_persona_header(args.persona)["size"]
    max_step = max(1, min(W, H) // 8)
    if not 1 <= args.step <= max_step:
        raise BadInputError(f"--step {args.step} leaves too few grid points in the {W}x{H} canonical frame: "
                            f"use 1..{max_step}", path=args.persona)
    t0 = time.perf_counter()
    persona = load_persona(args.persona)
    t1 = time.perf_counter()
    try:
        mesh = persona_mesh(persona, step=args.step, shape=args.shape)
    except BadInputError as e:
        raise BadInputError(e.message.replace("step ", "--step ", 1), path=args.persona) from None
    t2 = time.perf_counter()
    summary = {
        "command": "persona mesh", "persona": str(args.persona), "photos": len(persona),
        "paths": {k: str(v) for k, v in paths.items()},
        "vertices": int(len(mesh.vertices)), "faces": int(len(mesh.faces)), "step": args.step,
        "depth_source": mesh.depth_source, "depth_origin": mesh.depth_origin, "depth_photos": mesh.depth_photos,
        "shape_reason": mesh.shape_reason, "shape_validation": mesh.shape_validation,
        "units": "canonical px, OBJ axes (x right, y up, z towards the viewer)",
        "timings_s": {"load": t1 - t0, "mesh_texture": t2 - t1},
    }
    record = provenance(command="persona mesh", inputs={"persona": args.persona},
                        params={"step": args.step, "shape": args.shape},
                        outputs=[paths["obj"], paths["mtl"], paths["texture"]], result=summary)
    mesh.save(out, overwrite=args.overwrite, inputs=[args.persona],
              extra_files={paths["sidecar"]: encode_json(record)})
    if args.json:
        print_json(summary)
    else:  # which shape and why, on stderr beside the progress (stdout keeps the `wrote` lines)
        import sys

        print(f"{out}: {mesh.depth_source} shape ({mesh.shape_reason})", file=sys.stderr)
        wrote(args, *(paths[k] for k in ("obj", "mtl", "texture", "sidecar")))
    return 0
