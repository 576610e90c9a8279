"""``facetex identity IMAGE_A IMAGE_B`` — are two photos the same person (dlib face descriptors)?"""

from __future__ import annotations

from ._common import print_json


def register(sub) -> None:
    p = sub.add_parser("identity", help="face-recognition distance of the largest faces of two images")
    p.add_argument("image_a", help="first image")
    p.add_argument("image_b", help="second image")
    p.add_argument("--json", action="store_true", help='print {"distance": float, "same_person": bool}')
    p.set_defaults(func=run)


def run(args) -> int:
    from ..io import DETECT_MAX_PIXELS, read_image
    from ..landmarks import detect_face
    from ..nets.dlib_resnet import SAME_PERSON_THRESHOLD, identity_distance

    images, points = [], []
    for path in (args.image_a, args.image_b):
        image = read_image(path, reduce_to=DETECT_MAX_PIXELS)  # only the face chip is used
        images.append(image)
        points.append(detect_face(image, source=path).points68)
    distance = identity_distance(images[0], images[1], points_a=points[0], points_b=points[1])
    same = distance < SAME_PERSON_THRESHOLD
    if args.json:
        print_json({"distance": distance, "same_person": same})
    else:
        verdict = "same person" if same else "different people"
        print(f"distance {distance:.4f}: {verdict} (threshold {SAME_PERSON_THRESHOLD})")
    return 0
