"""``facetex landmarks IMAGE`` — detect faces and their 68 landmarks; print, JSON or overlay."""

from __future__ import annotations

from ._common import add_output, add_overwrite, nonnegative_int, print_json, wrote


def register(sub) -> None:
    p = sub.add_parser("landmarks", help="detect faces and their 68 iBUG landmarks")
    p.add_argument("image", help="input image")
    p.add_argument("--json", action="store_true",
                   help='print {"image": ..., "faces": [{"box": [x0,y0,x1,y1], "points68": [[x,y],...]}]} '
                        '(no face: "faces": [] and exit 0)')
    add_output(p, metavar="OVERLAY",
                   help="write the image with boxes and numbered points (e.g. overlay.png; OVERLAY.json gets "
                        "the parameters)")
    p.add_argument("--upsample", type=nonnegative_int, default=None, metavar="N",
                   help="double the image N times before detecting (default: automatic, "
                        "2x only when nothing is found in an image of at most 1200 px); the doubled "
                        "image may have at most 16 megapixels")
    p.add_argument("--detector", choices=("hog", "cnn"), default="hog",
                   help="dlib HOG (fast, default) or MMOD CNN (slow, more pose-robust)")
    p.add_argument("--face-index", type=nonnegative_int, default=0, metavar="K",
                   help="face to number in the overlay and mark in the summary (0 = largest)")
    add_overwrite(p)
    p.set_defaults(func=run)


def _overlay(image, faces, chosen: int):
    """uint8 RGB image with face boxes, points and (for the chosen face) point numbers."""
    import cv2
    import numpy as np

    from ..io import to_uint8

    img = np.ascontiguousarray(to_uint8(image))
    h, w = img.shape[:2]
    t = max(1, round(max(h, w) / 500))  # line width / dot radius grow with the image
    font = 0.25 * t
    for k, f in enumerate(faces):
        col = (0, 255, 0) if k == chosen else (255, 160, 0)
        x0, y0, x1, y1 = (int(round(v)) for v in f.box)
        cv2.rectangle(img, (x0, y0), (x1, y1), col, t, cv2.LINE_AA)
        cv2.putText(img, f"face {k}", (x0, max(0, y0 - 3 * t)), cv2.FONT_HERSHEY_SIMPLEX, 2 * font,
                    col, t, cv2.LINE_AA)
        for i, (x, y) in enumerate(f.points68):
            c = (int(round(x)), int(round(y)))
            cv2.circle(img, c, t + 1, (255, 0, 0), -1, cv2.LINE_AA)
            if k == chosen:
                cv2.putText(img, str(i), (c[0] + t + 1, c[1] - t), cv2.FONT_HERSHEY_SIMPLEX, font,
                            (255, 255, 0), max(1, t // 2), cv2.LINE_AA)
    return img


def max_upsample(width: int, height: int, limit: int) -> int:
    """Largest number of doublings that keeps a width x height image within ``limit`` pixels."""
    n = 0
    while width * height * 4 ** (n + 1) <= limit:
        n += 1
    return n


def run(args) -> int:
    import warnings

    from ..errors import BadInputError, NoFaceError
    from ..io import DETECT_MAX_PIXELS, IMAGE_EXTENSIONS, check_output_path, read_image_reduced
    from ..landmarks import detect_faces

    sidecar = None
    if args.output:  # fail before the work, not after it
        check_output_path(args.output, overwrite=args.overwrite, inputs=[args.image], extensions=IMAGE_EXTENSIONS,
                          what="image")
        sidecar = check_output_path(f"{args.output}.json", overwrite=args.overwrite, inputs=[args.image])
    image, scale = read_image_reduced(args.image, DETECT_MAX_PIXELS)
    h, w = image.shape[:2]
    factor = 2.0 / (scale[0] + scale[1])  # returned image -> original pixels
    if factor != 1.0:
        W, H = round(w * factor), round(h * factor)
        warnings.warn(f"{args.image}: {W}x{H} image reduced to {w}x{h} for detection (at most "
                      f"{DETECT_MAX_PIXELS // 10**6} megapixels); landmarks are in the original's pixels"
                      + ("; the overlay is written at the reduced size" if args.output else ""))
    else:
        W, H = w, h
    if args.upsample is not None and w * h * 4 ** args.upsample > DETECT_MAX_PIXELS:
        n = max_upsample(w, h, DETECT_MAX_PIXELS)
        raise BadInputError(f"--upsample {args.upsample} would detect on a {w * 2 ** args.upsample}x"
                            f"{h * 2 ** args.upsample} image, over the {DETECT_MAX_PIXELS // 10**6} megapixel limit: "
                            f"use at most --upsample {n} for this {w}x{h} image", path=args.image)
    faces = detect_faces(image, upsample=args.upsample, detector=args.detector)
    if not faces and args.json and not args.output:  # an answer, not an error: a script gets an empty list
        print_json({"image": str(args.image), "faces": []})
        return 0
    if not faces:
        raise NoFaceError("no face found: try --upsample 1 or --detector cnn, or a larger frontal photo",
                          path=args.image)
    k = args.face_index
    if not 0 <= k < len(faces):
        raise BadInputError(f"--face-index {k} is out of range: {len(faces)} face(s) found "
                            f"(use 0..{len(faces) - 1})", path=args.image)
    full = [f.scaled(factor) for f in faces] if factor != 1.0 else faces
    if args.output:
        import numpy as np

        from .._provenance import provenance
        from ..io import encode_image, encode_json, write_files

        record = provenance(
            command="landmarks", inputs={"image": args.image},
            params={"upsample": args.upsample, "detector": args.detector, "face_index": k,
                    "overlay_scale": 1.0 / factor},
            outputs=[args.output],
            faces=[{"box": [float(v) for v in f.box], "points68": np.asarray(f.points68).tolist()} for f in full])
        write_files({args.output: encode_image(args.output, _overlay(image, faces, k)),
                     sidecar: encode_json(record)}, overwrite=args.overwrite, inputs=[args.image])
    faces = full
    if args.json:
        print_json({
            "image": str(args.image),
            "faces": [{"box": [round(v, 2) for v in f.box],
                       "points68": [[round(float(x), 2), round(float(y), 2)] for x, y in f.points68]}
                      for f in faces],
        })
    else:
        print(f"{args.image}: {W}x{H}, {len(faces)} face(s) ({args.detector})")
        for i, f in enumerate(faces):
            x0, y0, x1, y1 = f.box
            p = f.points68
            iod = float(((p[36] - p[45]) ** 2).sum() ** 0.5)
            mark = "*" if i == k else " "
            print(f"{mark} face {i}: box ({x0:.0f}, {y0:.0f}, {x1:.0f}, {y1:.0f}) {x1 - x0:.0f}x{y1 - y0:.0f} px,"
                  f" score {f.score:.2f}, eye distance {iod:.1f} px")
        if args.output:
            wrote(args, args.output, sidecar)
    return 0
