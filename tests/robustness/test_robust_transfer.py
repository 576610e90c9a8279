"""``facetex transfer``: interrupt safety, same-seed determinism, memory budget, unusual inputs."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

import facetex.transfer._pipeline as pipeline
from _robust import assert_one_error, run_cli, snapshot

T = ["--size", "64", "--iters", "3"]  # 1 level, 4 loss evaluations (budget 1.25 × 3)


def test_keyboard_interrupt_leaves_nothing(capsys, bad, outdir, monkeypatch):
    real = pipeline.optimize_image
    calls = []

    def interrupted(*args, progress=None, **kwargs):
        def prog(*a, **k):
            calls.append(1)
            if len(calls) == 3:
                raise KeyboardInterrupt
            if progress:
                progress(*a, **k)
        return real(*args, progress=prog, **kwargs)

    monkeypatch.setattr(pipeline, "optimize_image", interrupted)
    run = run_cli(capsys, "transfer", bad["face.jpg"], bad["other.jpg"], "-o", outdir / "t.png", *T)
    assert len(calls) == 3
    assert_one_error(run, code=130, prefix="facetex:", cause="interrupted")
    assert snapshot(outdir) == {}  # no output, no sidecar, no temp file


def test_memory_budget_refuses_before_work(capsys, bad, outdir, monkeypatch):
    def work(*a, **k):
        raise AssertionError("the optimisation started despite the memory budget")

    monkeypatch.setattr(pipeline, "optimize_image", work)
    monkeypatch.setattr(pipeline, "_LossBuilder", work)
    run = run_cli(capsys, "transfer", bad["face.jpg"], bad["other.jpg"], "-o", outdir / "t.png",
                  *T, "--max-memory", "1M")
    assert_one_error(run, cause=r"memory|budget")
    assert snapshot(outdir) == {}


def test_same_seed_same_bytes(capsys, bad, outdir):
    for name in ("a.png", "b.png"):
        run = run_cli(capsys, "transfer", bad["face.jpg"], bad["other.jpg"], "-o", outdir / name, *T,
                      "--seed", "7", "--device", "cpu")
        assert run.code == 0, run.err
        assert run.lines == [], run.lines
    a, b = (outdir / "a.png").read_bytes(), (outdir / "b.png").read_bytes()
    assert a == b
    assert a != bad["face.jpg"].read_bytes()
    assert sorted(p.name for p in outdir.iterdir()) == ["a.png", "a.png.json", "b.png", "b.png.json"]


def test_unusual_encodings_transfer(capsys, bad, outdir):
    from facetex.io import read_image

    run = run_cli(capsys, "transfer", bad["cmyk.jpg"], bad["palette.png"], "-o", outdir / "t.jpg", *T)
    assert run.code == 0, run.err
    assert "Traceback" not in run.err and run.lines == [], run.lines
    out = read_image(outdir / "t.jpg")
    assert out.shape == (400, 400, 3)
    info = json.loads((outdir / "t.jpg.json").read_text())
    assert info["inputs"]["content"]["path"].endswith("cmyk.jpg")
    assert sorted(p.name for p in outdir.iterdir()) == ["t.jpg", "t.jpg.json"]
    # the face region changed, the corners (outside the face crop) did not
    src = read_image(bad["cmyk.jpg"])
    assert np.abs(out[:20, :20] - src[:20, :20]).max() < 0.03
    assert np.abs(out[150:250, 150:250] - src[150:250, 150:250]).mean() > 1e-3


@pytest.mark.parametrize("opts, cause", [(["--size", "0"], r"size"), (["--max-memory", "lots"], r"max-memory")])
def test_bad_option_values(capsys, bad, outdir, opts, cause):
    try:
        run = run_cli(capsys, "transfer", bad["face.jpg"], bad["other.jpg"], "-o", outdir / "t.png", *opts)
    except SystemExit as e:  # argparse rejects the value: usage line + one error line, exit 2
        assert e.code == 2
        err = capsys.readouterr().err
        assert "Traceback" not in err and re.search(cause, err.strip().splitlines()[-1])
    else:
        assert_one_error(run, cause=cause)
    assert snapshot(outdir) == {}
