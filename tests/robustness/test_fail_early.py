"""Issue 13: fail before the work, not after it; nonsense option values are rejected.

Every case asserts one ``facetex: error:`` line (exit 2) that names the cause (and the
file, where there is one), no traceback, nothing written, and that the work never started
(the input reader / the optimiser / the tracker is replaced by a trap)."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

import facetex.io as fio
import facetex.transfer._pipeline as pipeline
from _robust import assert_one_error, run_cli, sha1s, snapshot
from conftest import has_command

T = ["--size", "64", "--iters", "2"]


@pytest.fixture
def no_work(monkeypatch):
    """Make any real work fail the test: reading an image, loading a persona, optimising, tracking."""
    import facetex.persona as persona
    import facetex.puppet.puppetry as puppet

    def trap(*a, **k):
        raise AssertionError("the work started before the arguments were checked")

    # facetex.io's names for its callers, facetex.io._read's for as_image and read_image_uint8
    for mod, name in ((fio, "read_image"), (fio, "read_image_reduced"), (fio._read, "read_image"),
                      (fio._read, "read_image_reduced"), (persona, "load_persona"),
                      (persona, "build_persona"), (pipeline, "optimize_image"), (puppet, "puppeteer")):
        monkeypatch.setattr(mod, name, trap)


def _args(argv, bad, outdir, persona_file=None, videos=None):
    def one(a):
        if a == "%persona":
            return str(persona_file)
        if a.startswith("%video:"):
            return str(videos[a[7:]])
        if a.startswith("%"):
            return str(bad[a[1:]])
        if a.startswith("@"):
            return str(outdir / a[1:])
        return a
    return [one(a) for a in argv]


# (id, argv, files named, cause)
EARLY = [
    ("transfer-bad-extension", ["transfer", "%face.jpg", "%other.jpg", "-o", "@t.xyz", *T], ["@t.xyz"],
     r"extension '\.xyz'"),
    ("transfer-no-extension", ["transfer", "%face.jpg", "%other.jpg", "-o", "@t", *T], ["@t"], r"extension"),
    ("transfer-sidecar-is-folder", ["transfer", "%face.jpg", "%other.jpg", "-o", "@d.png", *T], ["@d.png.json"],
     r"directory"),
    ("transfer-cuda-missing", ["transfer", "%face.jpg", "%other.jpg", "-o", "@t.png", *T, "--device", "cuda"], [],
     r"--device cuda: CUDA is not available"),
    ("transfer-device-foo", ["transfer", "%face.jpg", "%other.jpg", "-o", "@t.png", "--device", "foo"], [],
     r"--device.*unknown device 'foo'"),
    ("transfer-iters-zero", ["transfer", "%face.jpg", "%other.jpg", "-o", "@t.png", "--iters", "0,0,0"], [],
     r"--iters.*at least 1 iteration"),
    ("transfer-iters-negative", ["transfer", "%face.jpg", "%other.jpg", "-o", "@t.png", "--iters=-3"], [],
     r"--iters.*at least 1 iteration"),
    ("transfer-iters-huge", ["transfer", "%face.jpg", "%other.jpg", "-o", "@t.png", "--iters", "99999999"], [],
     r"--iters.*at most"),
    ("transfer-size-huge", ["transfer", "%face.jpg", "%other.jpg", "-o", "@t.png", "--size", "99999"], [],
     r"--size.*from 32 to 4096"),
    ("transfer-save-every-zero", ["transfer", "%face.jpg", "%other.jpg", "-o", "@t.png", "--save-every", "0"],
     [], r"--save-every.*at least 1"),
    ("transfer-max-memory-inf", ["transfer", "%face.jpg", "%other.jpg", "-o", "@t.png", "--max-memory", "inf"],
     [], r"--max-memory.*finite"),
    ("transfer-max-memory-nan", ["transfer", "%face.jpg", "%other.jpg", "-o", "@t.png", "--max-memory", "nanG"],
     [], r"--max-memory.*finite"),
    ("transfer-max-memory-negative", ["transfer", "%face.jpg", "%other.jpg", "-o", "@t.png", "--max-memory=-8G"],
     [], r"--max-memory.*positive"),
    ("transfer-unknown-option", ["transfer", "%face.jpg", "%other.jpg", "-o", "@t.png", "--sizes", "64"], [],
     r"unrecognized arguments: --sizes"),
    ("demo-cuda-missing", ["demo", "--out", "@demo", "--device", "cuda"], [], r"CUDA is not available"),
    ("demo-unknown-method", ["demo", "--out", "@demo", "--methods", "facetex,magic"], [], r"--methods.*subset"),
    ("landmarks-overlay-extension", ["landmarks", "%face.jpg", "-o", "@o.gif"], ["@o.gif"], r"extension '\.gif'"),
    ("landmarks-face-index-negative", ["landmarks", "%face.jpg", "--face-index=-1"], [], r"--face-index.*at least 0"),
    ("persona-texture-extension", ["persona", "texture", "%persona", "--like", "%face.jpg", "-o", "@t.xyz"],
     ["@t.xyz"], r"extension"),
    ("persona-texture-sidecar-is-folder", ["persona", "texture", "%persona", "--like", "%face.jpg", "-o", "@d.png"],
     ["@d.png.json"], r"directory"),
    ("persona-texture-sigma-nan", ["persona", "texture", "%persona", "--like", "%face.jpg", "-o", "@t.png",
                                   "--sigma", "nan"], [], r"--sigma.*finite"),
    ("persona-texture-sigma-zero", ["persona", "texture", "%persona", "--like", "%face.jpg", "-o", "@t.png",
                                    "--sigma", "0"], [], r"--sigma.*above 0"),
    ("persona-average-extension", ["persona", "average", "%persona", "-o", "@a.txt"], ["@a.txt"], r"extension"),
    ("persona-build-extension", ["persona", "build", "%face.jpg", "-o", "@p.zip"], [], r"not a folder"),
    ("persona-build-jobs-zero", ["persona", "build", "@", "-o", "@p.persona", "--jobs", "0"], [], r"--jobs"),
    ("persona-mesh-step-huge", ["persona", "mesh", "%persona", "-o", "@m.obj", "--step", "100000"], ["%persona"],
     r"--step 100000 leaves too few grid points"),
    ("persona-mesh-step-zero", ["persona", "mesh", "%persona", "-o", "@m.obj", "--step", "0"], [],
     r"--step.*at least 1"),
    ("puppet-extension-xyz", ["puppet", "--driver", "%video:face.mp4", "--puppet", "%persona", "-o", "@o.xyz"],
     ["@o.xyz"], r"video extension '\.xyz'"),
    ("puppet-extension-png", ["puppet", "--driver", "%video:face.mp4", "--puppet", "%persona", "-o", "@o.png"],
     ["@o.png"], r"video extension '\.png'"),
    ("puppet-extension-persona", ["puppet", "--driver", "%video:face.mp4", "--puppet", "%persona", "-o",
                                  "@o.persona"], ["@o.persona"], r"video extension"),
    ("puppet-size-huge", ["puppet", "--driver", "%video:face.mp4", "--puppet", "%persona", "-o", "@o.mp4",
                          "--size", "99999"], [], r"--size.*from 32 to 4096"),
    ("puppet-max-frames-zero", ["puppet", "--driver", "%video:face.mp4", "--puppet", "%persona", "-o", "@o.mp4",
                                "--max-frames", "0"], [], r"--max-frames.*at least 1"),
    ("puppet-max-frames-negative", ["puppet", "--driver", "%video:face.mp4", "--puppet", "%persona", "-o",
                                    "@o.mp4", "--max-frames=-1"], [], r"--max-frames.*at least 1"),
    ("puppet-driver-photos-missing", ["puppet", "--driver", "%video:face.mp4", "--puppet", "%persona", "-o",
                                      "@o.mp4", "--driver-photos", "@nothing"], ["@nothing"], r"not found"),
    ("bench-puppet-clips-zero", ["bench", "puppet", "--clips", "0", "--out", "@b"], [], r"--clips.*at least 1"),
    ("bench-transfer-cuda-missing", ["bench", "transfer", "--device", "cuda", "--out", "@b"], [],
     r"CUDA is not available"),
    ("bench-persona-jobs-zero", ["bench", "persona", "--jobs", "0", "--out", "@b"], [], r"--jobs.*from 1 to \d+"),
]


@pytest.mark.parametrize("argv, names, cause", [c[1:] for c in EARLY], ids=[c[0] for c in EARLY])
def test_fails_before_the_work(capsys, bad, outdir, persona_file, videos, no_work, argv, names, cause):
    if argv[0] in ("puppet",) and not has_command("puppet"):
        pytest.skip("no puppet command")
    (outdir / "d.png.json").mkdir()
    before = snapshot(outdir)
    inputs = sha1s(bad["face.jpg"], bad["other.jpg"], persona_file)
    t0 = time.perf_counter()
    run = run_cli(capsys, *_args(argv, bad, outdir, persona_file, videos))
    took = time.perf_counter() - t0
    assert_one_error(run, names=_args(names, bad, outdir, persona_file, videos), cause=cause)
    assert snapshot(outdir) == before
    assert sha1s(bad["face.jpg"], bad["other.jpg"], persona_file) == inputs
    assert took < 10, took  # no optimisation, tracking or build ran (torch import included)


def test_upscale_warning_comes_before_the_optimisation(capsys, bad, outdir, monkeypatch):
    """The advice to pass a smaller --size is printed when it is known, not after the work."""
    seen = []

    def optimize(*a, **k):
        seen.append(capsys.readouterr().err)  # stderr so far, at the start of the optimisation
        raise KeyboardInterrupt  # the rest of the run does not matter here

    monkeypatch.setattr(pipeline, "optimize_image", optimize)
    run = run_cli(capsys, "transfer", bad["face.jpg"], bad["other.jpg"], "-o", outdir / "t.png",
                  "--size", "1000", "--iters", "1")
    assert run.code == 130
    assert seen and "upscaled" in seen[0] and "--size" in seen[0], seen
    assert snapshot(outdir) == {}


# ------------------------------------------------------------ fiducials
@pytest.mark.parametrize("points, cause", [
    ("nan", r"NaN or infinite values \(point 3\)"),
    ("inf", r"NaN or infinite values"),
    ("far", r"outside the persona's \d+x\d+ canonical frame"),
    ("negative", r"outside the persona's \d+x\d+ canonical frame"),
    ("collapsed", r"degenerate"),
])
def test_fiducials_nonsense(capsys, outdir, tmp_path, persona_file, no_work, points, cause):
    from facetex.persona import read_persona_header

    W, H = read_persona_header(persona_file)["size"]
    rng = np.random.default_rng(0)
    f = np.column_stack([rng.uniform(0.3 * W, 0.7 * W, 49), rng.uniform(0.3 * H, 0.7 * H, 49)])
    if points == "nan":
        f[3, 0] = np.nan
    elif points == "inf":
        f[10, 1] = np.inf
    elif points == "far":
        f *= 1e6
    elif points == "negative":
        f[0] = (-500, 20)
    elif points == "collapsed":
        f[:] = (W / 2, H / 2)
    path = tmp_path / "points.json"
    path.write_text(json.dumps({"fiducials": [[float(x) if np.isfinite(x) else str(x) for x in p] for p in f]})
                    .replace('"nan"', "NaN").replace('"inf"', "Infinity"))
    run = run_cli(capsys, "persona", "texture", persona_file, "--fiducials", path, "-o", outdir / "t.png")
    assert_one_error(run, names=[path], cause=cause)
    assert "got shape (49, 2)" not in run.err
    assert snapshot(outdir) == {}
