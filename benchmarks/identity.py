"""FaceRecognitionNet: parity with dlib, speed, and the same/different-person split on FRL London.

    python benchmarks/identity.py [--people 20] [--repeats 30]

Prints three tables: (1) max |ours - dlib| on dlib's own chips of the bundled samples and
the descriptor distance of our full pipeline (our chip) to dlib's full pipeline; (2) forward
and forward+backward time of a 150² chip, batch 1, on this CPU; (3) neutral-vs-smiling
distances of the same person against all pairs of different people.
"""

from __future__ import annotations

import argparse
import itertools
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

from facetex._resources import model_path, sample_path
from facetex.io import read_image
from facetex.landmarks import detect_face
from facetex.nets.dlib_resnet import SAME_PERSON_THRESHOLD, FaceRecognitionNet, face_descriptor

FRL = Path(__import__("os").environ.get("FACETEX_DATA", "FACETEX_DATA-not-set")) / "frl-london"  # data root: $FACETEX_DATA
SAMPLES = ("frl_003_neutral", "frl_004_neutral", "frl_004_smiling", "frl_005_neutral",
           "frl_005_smiling", "frl_008_neutral")


def _u8(img):
    return (img * 255 + 0.5).astype(np.uint8)


def parity(net) -> list[tuple[str, float, float]]:
    import dlib

    rec = dlib.face_recognition_model_v1(str(model_path("dlib_face_recognition_resnet_model_v1.dat")))
    sp = dlib.shape_predictor(str(model_path("shape_predictor_68_face_landmarks.dat")))
    rows = []
    for name in SAMPLES:
        img = read_image(sample_path(name + ".jpg"))
        face = detect_face(img)
        b = [int(round(v)) for v in face.box]
        shape = sp(_u8(img), dlib.rectangle(*b))
        pts = np.array([(p.x, p.y) for p in shape.parts()], dtype=np.float64)
        chip = dlib.get_face_chip(_u8(img), shape, size=150, padding=0.25)
        ref = np.array(rec.compute_face_descriptor(chip))
        x = torch.from_numpy(chip.astype(np.float32).transpose(2, 0, 1) / 255)[None]
        with torch.no_grad():
            ours = net(x)[0].double().numpy()
        full = np.linalg.norm(face_descriptor(img, pts) - np.array(rec.compute_face_descriptor(_u8(img), shape)))
        rows.append((name, float(np.abs(ours - ref).max()), float(full)))
    return rows


def timing(net, repeats: int) -> tuple[float, float]:
    x = torch.rand(1, 3, 150, 150)

    def fwd():
        with torch.no_grad():
            net(x)

    def fwd_bwd():
        xi = x.clone().requires_grad_(True)
        net(xi).square().sum().backward()

    out = []
    for fn in (fwd, fwd_bwd):
        for _ in range(3):
            fn()
        ts = []
        for _ in range(repeats):
            t = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t)
        out.append(1000 * statistics.median(ts))
    return out[0], out[1]


def identity(people: int):
    ids = sorted({p.name[:3] for p in FRL.glob("*_neutral.jpg") if (FRL / f"{p.name[:3]}_smiling.jpg").exists()})
    ids = ids[:people]
    desc = {}
    for k, pid in enumerate(ids):
        for expr in ("neutral", "smiling"):
            path = FRL / f"{pid}_{expr}.jpg"
            img = read_image(path)
            desc[pid, expr] = face_descriptor(img, detect_face(img, source=path).points68)
        print(f"\r  descriptors {k + 1}/{len(ids)}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    same = np.array([np.linalg.norm(desc[p, "neutral"] - desc[p, "smiling"]) for p in ids])
    diff = np.array([np.linalg.norm(desc[a, ea] - desc[b, eb])
                     for a, b in itertools.combinations(ids, 2)
                     for ea, eb in itertools.product(("neutral", "smiling"), repeat=2)])
    return ids, same, diff


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--people", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--threads", type=int, default=0, help="torch threads (default: torch's choice)")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)

    t = time.perf_counter()
    net = FaceRecognitionNet()
    build = time.perf_counter() - t
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, load average "
          f"{os.getloadavg()[0]:.1f}; net built in {build:.2f} s (parse cached after)")

    print("\n| sample | max abs diff vs dlib (dlib's chip) | distance ours vs dlib (own chips) |")
    print("|---|---|---|")
    for name, d, full in parity(net):
        print(f"| {name} | {d:.2e} | {full:.4f} |")

    fwd, fb = timing(net, args.repeats)
    print(f"\n| 150² chip, batch 1 | median ms ({args.repeats} runs) |\n|---|---|")
    print(f"| forward | {fwd:.1f} |\n| forward + backward (input grad) | {fb:.1f} |")

    ids, same, diff = identity(args.people)
    th = SAME_PERSON_THRESHOLD
    print(f"\n| FRL London, {len(ids)} people ({ids[0]}..{ids[-1]}) | pairs | min | mean | max | right side of {th} |")
    print("|---|---|---|---|---|---|")
    print(f"| same person (neutral vs smiling) | {len(same)} | {same.min():.3f} | {same.mean():.3f} | "
          f"{same.max():.3f} | {(same < th).sum()}/{len(same)} below |")
    print(f"| different people (all expr. pairs) | {len(diff)} | {diff.min():.3f} | {diff.mean():.3f} | "
          f"{diff.max():.3f} | {(diff >= th).sum()}/{len(diff)} above |")


if __name__ == "__main__":
    main()
