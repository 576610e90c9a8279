"""Wall time of the feature networks: forward and forward+backward to the input image.

Batch 1, torch threads = 2, median (or ``--stat min``) of ``--runs`` after one warm-up. "fwd" runs under
no_grad (as for fixed targets); "fwd+bwd" builds the graph from an input with
requires_grad and back-propagates a sum-of-squares loss to the pixels, as in pixel
optimisation. Run: ``python benchmarks/nets.py [--runs 5] [--sizes 256 512]``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch


def _wall_ms(fn, runs: int, stat: str = "median", clock=time.perf_counter) -> float:
    fn()  # warm-up
    times = []
    for _ in range(runs):
        t = clock()
        fn()
        times.append((clock() - t) * 1e3)
    return statistics.median(times) if stat == "median" else min(times)


def _loss(out) -> torch.Tensor:
    outs = out.values() if isinstance(out, dict) else [out]
    return sum(o.square().mean() for o in outs)


def time_net(call, size: int, runs: int, stat: str = "median", clock=time.perf_counter) -> tuple[float, float]:
    """(fwd ms, fwd+bwd ms) of ``call(x)`` on a random (1, 3, size, size) image."""
    x = torch.rand(1, 3, size, size)

    def fwd():
        with torch.no_grad():
            call(x)

    def fwd_bwd():
        xg = x.clone().requires_grad_(True)
        _loss(call(xg)).backward()

    return _wall_ms(fwd, runs, stat, clock), _wall_ms(fwd_bwd, runs, stat, clock)


def _cases():
    from facetex.nets.effnet import EfficientNetLite0Features
    from facetex.nets.vgg import VGG19Features

    vgg = VGG19Features("random")
    eff = EfficientNetLite0Features()
    cases = [
        ("VGG-19 to relu4_1 (random)", lambda x: vgg.features(x, ["relu3_1", "relu4_1"]), (256, 512)),
        ("VGG-19 to relu5_1 (random)", lambda x: vgg.features(x, ["relu1_1", "relu2_1", "relu3_1", "relu4_1", "relu4_2", "relu5_1"]), (256, 512)),
        ("EfficientNet-Lite0 all 16 blocks", lambda x: eff.features(x, ["block15"]), (256, 512)),
        ("EfficientNet-Lite0 to block 7", lambda x: eff.features(x, ["block2", "block4", "block7"]), (256, 512)),
    ]
    try:
        from facetex.nets.dlib_resnet import FaceRecognitionNet
    except ImportError as e:
        print(f"(FaceRecognitionNet skipped: {e})")
        return cases
    face = FaceRecognitionNet()
    cases.append(("dlib face ResNet, 150² chip -> descriptor", face, (150,)))
    spatial = [n for n in face.layer_names if n not in ("pool", "descriptor")]
    deepest = spatial[-1]  # the whole conv trunk (level5 in dlib_resnet's naming)
    cases.append((f"dlib face ResNet features to {deepest}", lambda x: face.features(x, [deepest]), (256, 512)))
    return cases


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--sizes", type=int, nargs="+", default=[256, 512])
    p.add_argument("--stat", choices=["median", "min"], default="median",
                   help="min is steadier when other jobs share the CPU")
    p.add_argument("--cpu", action="store_true",
                   help="report process CPU ms at 1 thread instead of wall ms at 2 (robust to a busy machine)")
    args = p.parse_args(argv)
    torch.set_num_threads(1 if args.cpu else 2)
    clock = time.process_time if args.cpu else time.perf_counter
    cols = sorted(set(args.sizes) | {150})
    rows = []
    for name, call, sizes in _cases():
        cells = {}
        for s in sizes:
            if s in cols and (s in args.sizes or s == 150):
                f, fb = time_net(call, s, args.runs, args.stat, clock)
                cells[s] = f"{f:.0f} / {fb:.0f}"
        rows.append((name, cells))
    cols = [c for c in cols if any(c in r for _, r in rows)]
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}, batch 1, {args.stat} of {args.runs}; "
          f"{'CPU' if args.cpu else 'wall'} ms fwd / fwd+bwd")
    print("| network | " + " | ".join(f"{c}²" for c in cols) + " |")
    print("|---|" + "---|" * len(cols))
    for name, cells in rows:
        print(f"| {name} | " + " | ".join(cells.get(c, "—") for c in cols) + " |")


if __name__ == "__main__":
    main()
