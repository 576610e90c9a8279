"""MRF loss cost vs the texture network, peak memory at 1000 px, and pystiche's MRF loss.

    python benchmarks/mrf_loss.py [--size 512] [--repeat 3] [--no-vgg] [--no-memory]
                                  [--pystiche /path/to/dir/with/pystiche]

(a) = MRF matching + loss + backward to the features, summed over the MRF layers, per
evaluation; (b) = the texture network's forward + backward (to the deepest layer a FaceTex
evaluation needs: EfficientNet block7, the content layer of the findings; VGG-19 relu4_1).
Features come from the bundled FRL portraits (content frl_004, style frl_005) at --size px.
pystiche (not a project dependency; it imports torchvision at package level, which this torch
lacks) is loaded from an unpacked ``pip install --no-deps --target DIR pystiche`` by importing
only ``pystiche/core``, ``misc`` and ``loss/functional.py`` under a stub package (and a stub
``torchvision.datasets.utils.check_md5``, which misc imports for downloads).
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import subprocess
import sys
import textwrap
import time
import types
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from facetex._resources import sample_path
from facetex.transfer.losses import extract_patches, mrf_loss, mrf_memory_estimate, style_patches

torch.set_num_threads(max(1, torch.get_num_threads()))


def _image(name: str, size: int) -> torch.Tensor:
    img = Image.open(sample_path(name)).convert("RGB").resize((size, size), Image.BICUBIC)
    return torch.from_numpy(np.asarray(img, np.float32) / 255.0).permute(2, 0, 1)[None].contiguous()


class _RandomEffNetLike(torch.nn.Module):
    """Stand-in with EfficientNet-Lite0's block2/block4/block7 strides (4, 8, 16) and widths."""

    def __init__(self):
        super().__init__()
        spec = [("block2", 3, 24, 4), ("block4", 24, 40, 2), ("block7", 40, 112, 2)]
        self.names = [n for n, *_ in spec]
        self.convs = torch.nn.ModuleList(torch.nn.Conv2d(i, o, 3, stride=st, padding=1) for _, i, o, st in spec)
        self.requires_grad_(False)

    def features(self, x, layers):
        out = {}
        for name, conv in zip(self.names, self.convs):
            x = torch.relu(conv(x))
            if name in layers:
                out[name] = x
        return out


def _timeit(fn, repeat: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _timeit_interleaved(fa, fb, repeat: int) -> tuple[float, float]:
    """Median times of two functions run alternately (fair on a machine with varying load)."""
    fa(), fb()
    ta, tb = [], []
    for _ in range(repeat):
        for f, acc in ((fa, ta), (fb, tb)):
            t0 = time.perf_counter()
            f()
            acc.append(time.perf_counter() - t0)
    return statistics.median(ta), statistics.median(tb)


def _net_fwd_bwd(net, x, layers):
    def run():
        xi = x.clone().requires_grad_(True)
        feats = net.features(xi, layers)
        sum(f.square().mean() for f in feats.values()).backward()
    return run


def _mrf_step(target, sp, **kw):
    def run():
        t = target.detach().clone().requires_grad_(True)
        mrf_loss(t, sp, **kw).backward()
    return run


def _bench_network(title, net, mrf_layers, deepest, content, style, repeat, rows, heavy_repeat=1):
    net_step = _net_fwd_bwd(net, content, mrf_layers + [deepest])
    with torch.no_grad():
        ft = net.features(content, mrf_layers)
        fs = net.features(style, mrf_layers)
    sps = {layer: style_patches(fs[layer]) for layer in mrf_layers}
    for variant in ("paper", "reference"):
        steps, parts, flops = [], [], 0.0
        for layer in mrf_layers:
            c, h, w = ft[layer].shape[1:]
            flops += (h - 2) * (w - 2) / (1 if variant == "paper" else 4) * len(sps[layer]) * c * 9 * 2
            steps.append(_mrf_step(ft[layer], sps[layer], variant=variant))
            parts.append(f"{layer} {c}×{h}×{w}")
        rep = heavy_repeat if flops > 5e10 else repeat
        # Alternate the network and the MRF step so both see the same machine load.
        t_net, total = _timeit_interleaved(net_step, lambda: [f() for f in steps], rep)
        rows.append((title, variant, ", ".join(parts), f"{flops / 1e9:.0f}", f"{total * 1000:.0f}",
                     f"{t_net * 1000:.0f}", f"{100 * total / t_net:.0f}%"))
    return ft, fs


def _measure_peak(channels, hw, variant):
    # VmHWM, not ru_maxrss: the latter survives exec and would report this (large) process's peak.
    code = textwrap.dedent(f"""
        import torch
        from facetex.transfer.losses import mrf_loss
        from facetex._memory import peak_rss, reset_peak_rss
        t = torch.rand(1, {channels}, {hw[0]}, {hw[1]}, requires_grad=True)
        s = torch.rand(1, {channels}, {hw[0]}, {hw[1]})
        mrf_loss(t[..., :8, :8], s[..., :8, :8]).backward(); t.grad = None
        base = reset_peak_rss()
        mrf_loss(t, s, variant="{variant}").backward()
        print(peak_rss() - base)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return int(out.stdout.strip())


def _load_pystiche(directory: Path):
    """pystiche.cosine_similarity and loss.functional.mrf_loss without its torchvision imports."""
    root = directory / "pystiche"
    # pystiche.misc imports torchvision.datasets.utils.check_md5 (for downloads, unused here):
    # a stub module stands in for it; nothing else of torchvision is touched.
    if importlib.util.find_spec("torchvision") is None:
        tv = types.ModuleType("torchvision.datasets.utils")
        tv.check_md5 = lambda *a, **k: True
        for name in ("torchvision", "torchvision.datasets"):
            sys.modules.setdefault(name, types.ModuleType(name))
        sys.modules["torchvision.datasets.utils"] = tv
    pkg = types.ModuleType("pystiche")
    pkg.__path__ = [str(root)]
    sys.modules["pystiche"] = pkg
    import pystiche.core as core  # noqa: E402  (core, misc and meta need torch only)

    for name in core.__all__ if hasattr(core, "__all__") else dir(core):
        setattr(pkg, name, getattr(core, name))
    import pystiche.misc  # noqa: F401,E402

    spec = importlib.util.spec_from_file_location("pystiche_loss_functional", root / "loss" / "functional.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return core, mod


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-vgg", action="store_true")
    ap.add_argument("--no-memory", action="store_true")
    ap.add_argument("--pystiche", type=Path, default=None, help="directory holding an unpacked pystiche package")
    args = ap.parse_args(argv)
    torch.manual_seed(0)
    content, style = _image("frl_004_neutral.jpg", args.size), _image("frl_005_neutral.jpg", args.size)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, input {args.size}×{args.size}\n")

    rows = []
    try:
        from facetex.nets.effnet import EfficientNetLite0Features
        eff, eff_name = EfficientNetLite0Features(), "EfficientNet-Lite0 (ImageNet)"
    except Exception as exc:  # noqa: BLE001 — fall back to a comparable random net, and say so
        print(f"facetex.nets.effnet unavailable ({exc}); using a random conv net of the same strides and widths")
        eff, eff_name = _RandomEffNetLike(), "random conv net (EfficientNet-Lite0 widths/strides)"
    ft, fs = _bench_network(eff_name, eff, ["block2", "block4"], "block7", content, style, args.repeat, rows)
    if not args.no_vgg:
        from facetex.nets.vgg import VGG19Features
        vgg = VGG19Features(weights="random")
        _bench_network("VGG-19 (random weights)", vgg, ["relu3_1", "relu4_1"], "relu4_1", content, style,
                       max(1, args.repeat - 2), rows)
    print("| network | MRF variant | MRF layers | matching GFLOP | (a) MRF ms | (b) net fwd+bwd ms | a/b |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")

    if not args.no_memory:
        print("\nPeak extra memory of one mrf_loss call + backward at 1000 px (style 1000 px, stride 2)")
        print("| layer | feature map | N_t × N_s matrix would be | estimate | measured (RSS growth) |")
        print("|---|---|---|---|---|")
        shapes = [("EffNet block2", 24, 250), ("EffNet block4", 40, 125), ("VGG relu4_1", 512, 125),
                  ("VGG relu3_1", 256, 250)]
        for name, c, n in shapes:
            n_t, n_s = (n - 2) ** 2, len(extract_patches(torch.zeros(1, n, n), 3, 2)) ** 1
            est = mrf_memory_estimate(c, (n, n), (n, n))
            flops = n_t * n_s * c * 9 * 2
            measured = f"{_measure_peak(c, (n, n), 'paper') / 2**20:.0f} MiB" if flops < 5e11 else \
                f"not run ({flops / 1e12:.1f} TFLOP)"
            print(f"| {name} | {c}×{n}×{n} | {n_t * n_s * 4 / 2**20:.0f} MiB | {est / 2**20:.0f} MiB | {measured} |")

    if args.pystiche is not None:
        print("\npystiche 1.0.1 loss.functional.mrf_loss vs facetex mrf_loss (same style patches, "
              "target stride 1, mean reduction), match + loss + backward")
        try:
            core, pf = _load_pystiche(args.pystiche)
        except Exception as exc:  # noqa: BLE001
            print(f"pystiche could not be imported from {args.pystiche}: {exc}")
            return 0
        print("| layer | pystiche ms | facetex ms | pystiche / facetex | loss values (pystiche, facetex) |")
        print("|---|---|---|---|---|")
        for layer in ("block2", "block4"):
            t_feat, s_feat = ft[layer], fs[layer]
            c = t_feat.shape[1]
            sp_ours = style_patches(s_feat)
            sp_theirs = extract_patches(s_feat, 3, 2)[None]  # (1, N_s, C, 3, 3)
            n_t = (t_feat.shape[2] - 2) * (t_feat.shape[3] - 2)
            vals = {}

            def run_pystiche():
                t = t_feat.detach().clone().requires_grad_(True)
                patches = core.extract_patches2d(t, 3, 1)  # (1, N_t, C, 3, 3)
                loss = pf.mrf_loss(patches, sp_theirs, reduction="mean", batched_input=True)
                loss.backward()
                vals["pystiche"] = loss.item()

            def run_ours():
                t = t_feat.detach().clone().requires_grad_(True)
                loss = mrf_loss(t, sp_ours, reduction="mean") / (c * 9)
                loss.backward()
                vals["facetex"] = loss.item()

            tp, to = _timeit_interleaved(run_pystiche, run_ours, args.repeat)
            print(f"| {layer} ({n_t} × {len(sp_ours)} patches) | {tp * 1000:.0f} | {to * 1000:.0f} | {tp / to:.2f} | "
                  f"{vals['pystiche']:.6g}, {vals['facetex']:.6g} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
