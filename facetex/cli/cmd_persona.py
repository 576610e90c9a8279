"""``facetex persona build|texture|average|mesh`` — persona textures and average 3D face from a photo
collection (Tom Hanks Sec. 4-5)."""

from __future__ import annotations

from ._common import add_overwrite, print_json, progress_bar


def register(sub) -> None:
    p = sub.add_parser("persona", help="build a persona from photos of one person; synthesize its textures")
    ps = p.add_subparsers(dest="persona_command", metavar="ACTION")
    ps.required = True

    b = ps.add_parser("build", help="detect, frontalize and align a folder of photos into a .persona file")
    b.add_argument("photo_dir", metavar="PHOTO_DIR", help="folder of photos of one person (>= 10 usable)")
    b.add_argument("-o", "--output", required=True, metavar="PERSON.persona", help="persona file to write")
    b.add_argument("--jobs", type=int, default=2, metavar="N", help="worker processes (default 2)")
    b.add_argument("--min-photos", type=int, default=10, metavar="N",
                   help="fewest usable photos accepted (default 10)")
    add_overwrite(b)
    b.set_defaults(func=run_build)

    t = ps.add_parser("texture", help="synthesize a texture for a target expression")
    t.add_argument("persona", metavar="PERSON.persona")
    g = t.add_mutually_exclusive_group(required=True)
    g.add_argument("--like", metavar="REF_IMAGE", help="reference photo giving the target expression")
    g.add_argument("--fiducials", metavar="POINTS.json",
                   help='target fiducials in the canonical frame: a JSON list of 49 (or 68) [x, y] '
                        'or {"fiducials": [...]}')
    t.add_argument("-o", "--output", required=True, metavar="OUT.png")
    t.add_argument("--method", choices=("ours", "static", "weighted", "prewarp"), default="ours",
                   help="ours (default) or a Fig. 5 baseline")
    t.add_argument("--weights", choices=("regional", "global"), default="regional",
                   help="expression weights: regional (default: mouth, eyes and the rest of the face each "
                        "weighted by their own fiducials) or global (the paper's Eq. 2/3: all fiducials, sigma, "
                        "Laplacian weighting alpha 1)")
    t.add_argument("--sigma", type=float, default=None,
                   help="--weights global only: sigma of Eq. 2/3 (default 10, typically 6-12)")
    t.add_argument("--neighbours", type=int, default=None, metavar="K",
                   help="--weights regional only: each region's sigma is the target's distance to its K-th "
                        "nearest photo / 2 (default 3)")
    add_overwrite(t)
    t.set_defaults(func=run_texture)

    a = ps.add_parser("average", help="the persona's average face (Fig. 6 stages a-d)")
    a.add_argument("persona", metavar="PERSON.persona")
    a.add_argument("-o", "--output", required=True, metavar="OUT.png")
    a.add_argument("--stage", choices=("a", "b", "c", "d"), default="d",
                   help="a: frontalized, b: + TPS, c: + dense warp, d: + multi-scale blend (default)")
    add_overwrite(a)
    a.set_defaults(func=run_average)

    m = ps.add_parser("mesh", help="the persona's average 3D face as an .obj (+ .mtl, .png texture)")
    m.add_argument("persona", metavar="PERSON.persona")
    m.add_argument("-o", "--output", required=True, metavar="FACE.obj",
                   help="mesh to write; FACE.mtl and FACE.png (stage-d average texture) go beside it")
    m.add_argument("--step", type=int, default=1, metavar="N", help="grid step of the mesh in canonical px (default 1)")
    m.add_argument("--shape", choices=("collection", "generic"), default="collection",
                   help="collection: the persona's photometric-stereo average depth when it passed its "
                        "photometric validation on held-out photos (default; else the generic face, and the "
                        "report says why); generic: the generic face")
    add_overwrite(m)
    m.set_defaults(func=run_mesh)


def _sidecar(out, record: dict) -> None:
    """OUT.png.json beside the image (replaced with it: the image itself was allowed)."""
    from ..io import write_json

    write_json(f"{out}.json", record, overwrite=True)


def run_build(args) -> int:
    import time
    from pathlib import Path

    from ..errors import BadInputError
    from ..io import check_output_path
    from ..persona import PersonaParams, build_persona

    check_output_path(args.output, overwrite=args.overwrite)
    if args.jobs < 1 or args.min_photos < 3:
        raise BadInputError("--jobs must be >= 1 and --min-photos >= 3")
    folder = Path(args.photo_dir)
    from ..persona.collection import _list_photos

    n = len(_list_photos(folder))
    t0 = time.perf_counter()
    with progress_bar(total=2 * n, desc="persona", unit="photo") as update:
        persona = build_persona(folder, jobs=args.jobs, progress=update,
                                params=PersonaParams(min_photos=args.min_photos))
    persona.save(args.output, overwrite=args.overwrite)
    import sys

    print(f"{args.output}: {len(persona)} photos used, {len(persona.skipped)} skipped "
          f"({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    for s in persona.skipped:
        print(f"  skipped {s['file']}: {s['reason']}", file=sys.stderr)
    return 0


def _read_fiducials(path):
    import json

    import numpy as np

    from ..errors import BadInputError

    try:
        obj = json.loads(open(path, encoding="utf-8").read())
    except FileNotFoundError:
        raise BadInputError("fiducials file not found", path=path) from None
    except (OSError, ValueError) as e:
        raise BadInputError(f"unreadable fiducials JSON ({e}): give a list of 49 [x, y] points", path=path) from None
    if isinstance(obj, dict):
        obj = obj.get("fiducials", obj.get("points49", obj.get("points68")))
    try:
        a = np.asarray(obj, dtype=np.float64)
    except (TypeError, ValueError):
        a = np.empty(0)
    if a.shape not in ((49, 2), (68, 2)) or not np.all(np.isfinite(a)):
        raise BadInputError(f"fiducials must be 49 (or 68) [x, y] points, got shape {a.shape}", path=path)
    return a


def run_texture(args) -> int:
    import time

    from ..io import check_output_path, write_image
    from ..persona import load_persona, synthesize_texture

    check_output_path(args.output, overwrite=args.overwrite)
    t0 = time.perf_counter()
    persona = load_persona(args.persona)
    t1 = time.perf_counter()
    import dataclasses

    from ..errors import BadInputError
    from ..persona import TextureParams

    if args.sigma is not None and args.weights != "global":
        raise BadInputError("--sigma applies to --weights global (the regional weights measure their own "
                            "sigma: use --neighbours)")
    if args.neighbours is not None and (args.weights != "regional" or args.neighbours < 1):
        raise BadInputError("--neighbours is a positive integer and applies to --weights regional")
    tp = TextureParams(weights=args.weights)
    if args.sigma is not None:
        tp = dataclasses.replace(tp, sigma=args.sigma)
    if args.neighbours is not None:
        tp = dataclasses.replace(tp, neighbours=args.neighbours)
    kw = {"reference": args.like} if args.like else {"fiducials": _read_fiducials(args.fiducials)}
    with progress_bar(desc="texture", unit="step") as update:
        img = synthesize_texture(persona, method=args.method, params=tp, progress=update, **kw)
    t2 = time.perf_counter()
    write_image(args.output, img, overwrite=args.overwrite)
    _sidecar(args.output, {
        "command": "persona texture", "persona": args.persona, "photos": len(persona),
        "target": {"like": args.like} if args.like else {"fiducials": args.fiducials},
        "method": args.method, "weights": tp.weights,
        "sigma": tp.sigma if tp.weights == "global" else None,
        "neighbours": tp.neighbours if tp.weights == "regional" else None,
        "timings_s": {"load": t1 - t0, "synthesize_incl_precompute": t2 - t1},
    })
    return 0


def run_average(args) -> int:
    import time

    from ..io import check_output_path, write_image
    from ..persona import average_face, load_persona

    check_output_path(args.output, overwrite=args.overwrite)
    t0 = time.perf_counter()
    persona = load_persona(args.persona)
    t1 = time.perf_counter()
    img = average_face(persona, args.stage)
    t2 = time.perf_counter()
    write_image(args.output, img, overwrite=args.overwrite)
    _sidecar(args.output, {"command": "persona average", "persona": args.persona, "photos": len(persona),
                           "stage": args.stage, "timings_s": {"load": t1 - t0, "average": t2 - t1}})
    return 0


def run_mesh(args) -> int:
    import time
    from pathlib import Path

    from ..errors import BadInputError, OutputError
    from ..io import check_output_path
    from ..persona import average_face, load_persona
    from ..persona.collection import average_shape, face_region
    from ..persona.mesh_io import depth_to_mesh, write_obj
    from ..persona.shape import checked_depth, generic_depth_px

    out = Path(args.output)
    if out.suffix.lower() != ".obj":
        raise OutputError("mesh file name must end in .obj", path=out)
    if args.step < 1:
        raise BadInputError(f"--step must be a positive integer, got {args.step}")
    paths = {"obj": out, "mtl": out.with_suffix(".mtl"), "texture": out.with_suffix(".png")}
    for p in paths.values():  # before any work: no partial output set
        check_output_path(p, overwrite=args.overwrite)
    t0 = time.perf_counter()
    persona = load_persona(args.persona)
    W, H = persona.size
    region = face_region(persona.points68.mean(axis=0), (H, W))
    t1 = time.perf_counter()
    origin, n_used, validation = None, 0, None
    if args.shape == "generic":
        depth, source = generic_depth_px((W, H)).astype("float64"), "generic"
        reason = "--shape generic"
    else:
        if persona.shape_report is not None:  # validated at build time
            raw, n_used, origin, validation = persona.depth, persona.depth_photos, "stored", persona.shape_report
            if not validation.get("accepted"):
                raw, n_used = None, 0
        else:  # a version-1 persona, or one built before the validation: reconstruct and validate now
            raw, n_used, validation = average_shape(persona)
            origin = "computed"
            if not validation.get("accepted"):
                raw, n_used = None, 0
        depth, source = checked_depth(raw, region, (W, H))
        if source == "collection":
            reason = validation.get("reason", "")
        elif validation is not None and not validation.get("accepted"):
            reason = f"generic face: {validation.get('reason', 'the shape was rejected')}"
        else:
            reason = ("generic face: the validated depth is implausible (RMS difference to the generic face "
                      "above 8 % of the frame width)")
    t2 = time.perf_counter()
    vertices, faces, uv = depth_to_mesh(depth, region, step=args.step)
    texture = average_face(persona, "d")
    t3 = time.perf_counter()
    write_obj(out, vertices, faces, uv, texture, overwrite=args.overwrite)
    print_json({
        "command": "persona mesh", "persona": str(args.persona), "photos": len(persona),
        "paths": {k: str(v) for k, v in paths.items()},
        "vertices": int(len(vertices)), "faces": int(len(faces)), "step": args.step,
        "depth_source": source, "depth_origin": origin, "depth_photos": int(n_used), "shape_reason": reason,
        "shape_validation": validation,
        "units": "canonical px, OBJ axes (x right, y up, z towards the viewer)",
        "timings_s": {"load": t1 - t0, "depth": t2 - t1, "mesh_texture": t3 - t2,
                      "write": time.perf_counter() - t3},
    })
    return 0
