"""Run folders for the report tests: `facetex bench transfer` on the bundled samples with a
cheap stand-in for the transfer (a content/style blend) and for the metrics, so the folders
have the real layout (results.json, images/, results/, table.md, run.json) in seconds."""

from __future__ import annotations

import argparse
import shutil

import numpy as np
import pytest

from facetex._resources import sample_path

PEOPLE = ("003", "004", "005", "008")


def blend(weight):
    def transfer(content, style, *, method, preset, seed, device, progress=None, **options):
        w = {"gatys": 0.1, "mrf": 0.3, "facetex": 0.2}[method] * weight
        return (1 - w) * content + w * style, {"timings": {"total_s": 0.01}, "params": {"method": method},
                                               "images": {"big": np.zeros((300, 300, 3), np.float32)}}
    return transfer


def quick_metrics(output, content, style, *, points=None):
    dc, ds = float(np.mean((output - content) ** 2)), float(np.mean((output - style) ** 2))
    return {"E_content": 1000 * dc, "E_style": 1000 * ds, "E_content_rms_px": dc ** 0.5, "E_style_rms_px": ds ** 0.5,
            "S_content": 1 - dc, "S_style": 1 - ds, "identity_content": 3 * dc, "identity_style": 3 * ds}


def make_run(out, data, monkeypatch, *, weight=1.0, seed=0, methods="gatys,mrf,facetex", pairs=3):
    from facetex.bench import transfer as bench

    monkeypatch.setattr(bench, "_default_transfer_fn", lambda: blend(weight))
    monkeypatch.setattr("facetex.metrics.transfer_metrics", quick_metrics)
    parser = argparse.ArgumentParser()
    bench.register_bench(parser.add_subparsers())
    args = parser.parse_args(["transfer", "--data", str(data), "--out", str(out), "--pairs", str(pairs), "--jobs", "1",
                              "--methods", methods, "--seed", str(seed), "-q"])
    assert args.func(args) == 0
    return out


@pytest.fixture(scope="session")
def frl(tmp_path_factory):
    d = tmp_path_factory.mktemp("frl")
    for p in PEOPLE:
        shutil.copy(sample_path(f"frl_{p}_neutral.jpg"), d / f"{p}_neutral.jpg")
    return d


@pytest.fixture(scope="session")
def runs(frl, tmp_path_factory):
    mp = pytest.MonkeyPatch()
    try:
        root = tmp_path_factory.mktemp("runs")
        a = make_run(root / "run_a", frl, mp, weight=1.0)
        b = make_run(root / "run_b", frl, mp, weight=2.0, seed=0)
    finally:
        mp.undo()
    return a, b


@pytest.fixture(scope="session")
def run10(tmp_path_factory):
    """A 10-pair transfer bench at the real data's size: the four sample portraits enlarged to
    1000 px with pixel noise (texture that compresses as badly as skin does), 12 possible pairs."""
    import cv2

    from facetex.io import read_image, write_image

    data = tmp_path_factory.mktemp("frl1000")
    rng = np.random.default_rng(0)
    for p in PEOPLE:
        img = cv2.resize(read_image(sample_path(f"frl_{p}_neutral.jpg")), (1000, 1000), interpolation=cv2.INTER_CUBIC)
        img = np.clip(img + rng.normal(0, 0.02, img.shape).astype(np.float32), 0, 1)
        write_image(data / f"{p}_neutral.jpg", img)
    mp = pytest.MonkeyPatch()
    try:
        out = make_run(tmp_path_factory.mktemp("runs10") / "run10", data, mp, pairs=10)
    finally:
        mp.undo()
    return out, data
